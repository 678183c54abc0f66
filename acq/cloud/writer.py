"""The coloured cloud's file, written chunk by chunk (step 5 of :mod:`acq.cloud.colorize`):
PLY or LAS by the output's extension, under a temporary name renamed at the end."""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from acq.cloud.chunks import ChunkResult
from acq.cloud.las import LasStream
from acq.cloud.ply import PlyStream
from acq.cloud.report import Report
from acq.errors import InputValueError
from acq.time.utc import utc_seconds

__all__ = ["FORMATS", "CloudWriter"]

FORMATS = (".ply", ".las", ".laz")


@contextmanager
def _naming(output: Path) -> Iterator[None]:
    """An OSError writing ``output`` (really its temporary file) names ``output``."""
    try:
        yield
    except OSError as e:
        raise OSError(e.errno, e.strerror or str(e), str(output)) from e


class CloudWriter:
    """The output file, written chunk by chunk in chunk order: PLY or LAS by
    ``output``'s extension; ``seconds`` spent writing. Its OSErrors name ``output``."""

    def __init__(self, output: Path, crs: str | None, clock: np.ndarray, report: Report) -> None:
        self.output = output
        suffix = output.suffix.lower()
        comments = [f"frame {report.frame}", f"view {report.view}", *(
            [f"crs {crs}"] if crs else [])]  # fmt: skip
        self.stream: PlyStream | LasStream
        if suffix == ".ply":
            with _naming(output):
                self.stream = PlyStream(output, comments)
            if crs:
                report.notes.append("PLY has no CRS field: --crs written as a comment")
        elif suffix in (".las", ".laz"):
            with _naming(output):
                self.stream = LasStream(output, crs=crs, comments=comments)
        else:
            raise InputValueError(f"{output}: unknown format; expected {', '.join(FORMATS)}")
        self.clock = clock
        self.seconds = 0.0

    def write(self, r: ChunkResult) -> None:
        t0 = time.perf_counter()
        utc = utc_seconds(r.time_ns, self.clock)
        with _naming(self.output):
            self.stream.write(r.xyz, r.rgb, utc, r.intensity, r.scan, r.coloured)
        self.seconds += time.perf_counter() - t0

    def close(self) -> int:
        """Close and rename into place; the file's size in bytes."""
        with _naming(self.output):
            return self.stream.close()
