"""The coloured cloud's file, written chunk by chunk (step 5 of :mod:`acq.cloud.colorize`):
PLY, LAS, LAZ, COPC or E57 by the output's suffix (:func:`format_of`), under a temporary name
renamed at the end; a full disk is said as such, naming the output and the disk. Every
point keeps the camera and frame it was coloured from, and the file names the cameras
(each format's way: see its module)."""

from __future__ import annotations

import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from acq.cloud.chunks import NO_CAMERA, ChunkResult
from acq.cloud.copc import CopcStream
from acq.cloud.e57 import E57Stream
from acq.cloud.las import LasStream
from acq.cloud.ply import PlyStream
from acq.cloud.report import Report
from acq.disk_space import full_disk_error
from acq.errors import InputValueError
from acq.extras import require
from acq.output_suffix import suffix_format
from acq.time.utc import utc_seconds

__all__ = ["FORMATS", "CloudWriter", "format_of"]

FORMATS = (".ply", ".las", ".laz", ".copc.laz", ".e57")


def format_of(output: Path, option: str = "-o") -> str:
    """The format ``output``'s suffix names ("ply", "las", "laz", "copc", "e57");
    InputValueError naming ``option`` and the accepted suffixes for any other."""
    kind = suffix_format(output, FORMATS, "cloud", option)
    if kind == "copc.laz":
        require("copc", f"{option} {output}: COPC output")
    elif kind == "e57":
        require("e57", f"{option} {output}: E57 output")
    return "copc" if kind == "copc.laz" else kind


@contextmanager
def _naming(output: Path) -> Iterator[None]:
    """An error writing ``output`` (really its temporary file) that came from a full disk
    is the :class:`acq.errors.DiskFullError` naming ``output`` and its disk (the
    libraries' own, LazrsError, E57Exception, hide it: :mod:`acq.disk_space`); another
    OSError names ``output``."""
    try:
        yield
    except Exception as e:
        full = full_disk_error(output, e)
        if full is not None:
            raise full from e
        if isinstance(e, OSError):
            raise OSError(e.errno, e.strerror or str(e), str(output)) from e
        raise


class CloudWriter:
    """The output file, written chunk by chunk in chunk order: PLY, LAS, LAZ, COPC or E57 by
    ``output``'s suffix; ``seconds`` spent writing. Its errors name ``output`` (a full
    disk: :class:`acq.errors.DiskFullError`). ``cameras``: the job's camera names, in the
    order the points' ``camera`` indexes; InputValueError for more than 255 (255 is
    :data:`NO_CAMERA`) or a name that is not one line of printable ASCII (the formats'
    headers hold them as text lines). ``utc_doubt``: why the points' UTC cannot be trusted
    (:func:`acq.time.host_clock_summary.utc_doubt`), written as a comment (in LAS, whose
    files have no comments, as a VLR); ``checks``, the calibration check's lines, too
    (COPC, whose writer takes no VLR of ours, has neither)."""

    def __init__(
        self, output: Path, crs: str | None, clock: np.ndarray, report: Report,
        cameras: Sequence[str] = (), utc_doubt: str | None = None, checks: Sequence[str] = (),
    ) -> None:  # fmt: skip
        self.output = output
        kind = format_of(output)
        if len(cameras) > NO_CAMERA:
            raise InputValueError(
                f"{len(cameras)} cameras: a cloud names at most {NO_CAMERA} (index "
                f"{NO_CAMERA} means none)"
            )
        for name in cameras:
            if not (name and name.isascii() and name.isprintable()):
                raise InputValueError(
                    f"camera {name!r}: a cloud names its cameras in one line of printable "
                    "ASCII each"
                )
        self.cameras = cameras = list(cameras)
        comments = [f"frame {report.frame}", f"view {report.view}", *(
            [f"crs {crs}"] if crs else [])]  # fmt: skip
        if utc_doubt is not None:
            comments.append(f"UTC not trusted: {utc_doubt}")
        comments += checks
        self.stream: PlyStream | LasStream | CopcStream | E57Stream
        if kind == "ply":
            with _naming(output):
                self.stream = PlyStream(output, comments, cameras)
            if crs:
                report.notes.append("PLY has no CRS field: --crs written as a comment")
        elif kind == "copc":
            with _naming(output):
                self.stream = CopcStream(output, crs=crs, comments=comments, cameras=cameras)
        elif kind == "e57":
            with _naming(output):
                self.stream = E57Stream(output, crs=crs, comments=comments, cameras=cameras)
        else:
            with _naming(output):
                self.stream = LasStream(output, crs=crs, comments=comments, cameras=cameras,
                                        utc_doubt=utc_doubt, checks=checks)  # fmt: skip
        self.clock = clock
        self.seconds = 0.0

    def write(self, r: ChunkResult) -> None:
        """Append a chunk's points; ValueError if one names a camera the file does not."""
        t0 = time.perf_counter()
        named = (r.camera < len(self.cameras)) | (r.camera == NO_CAMERA)
        if not named.all():
            raise ValueError(
                f"a point's camera {int(r.camera[~named][0])} is not one of the "
                f"{len(self.cameras)} the cloud names"
            )
        utc = utc_seconds(r.time_ns, self.clock)
        with _naming(self.output):
            self.stream.write(r.xyz, r.rgb, utc, r.intensity, r.scan, r.coloured, r.camera, r.frame)
        self.seconds += time.perf_counter() - t0

    def close(self) -> int:
        """Close and rename into place; the file's size in bytes."""
        with _naming(self.output):
            return self.stream.close()
