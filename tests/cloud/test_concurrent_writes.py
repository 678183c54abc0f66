"""Two commands writing one output at once (two `acq colorize -o z.ply`, two calibrations
saved to one file): each writes into a temporary of its own and renames it, so the
output is always one whole file, the one its last writer closed, and each "wrote" holds
for the file it closed. They once shared the fixed temporary OUT.tmp, and a run
reported "wrote z.ply" over the other run's cloud. Both writers run in this process,
interleaved part by part as two processes would be, on real files."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import laspy
import numpy as np
import pytest
from plyfile import PlyData

from acq.camera import calibfile
from acq.cloud.copc import CopcStream
from acq.cloud.e57 import E57Stream
from acq.cloud.las import LasStream
from acq.cloud.ply import PlyStream
from tests.cloud.test_cloud_files import _points


def _x_ply(path: Path) -> np.ndarray:
    return np.asarray(PlyData.read(str(path))["vertex"].data["x"])


def _x_las(path: Path) -> np.ndarray:
    return np.asarray(laspy.read(path).x)


def _x_e57(path: Path) -> np.ndarray:
    import pye57

    return np.asarray(
        pye57.E57(str(path)).read_scan_raw(0, ignore_unsupported_fields=True)["cartesianX"]
    )


WRITERS: dict[str, tuple[Callable[[Path], Any], Callable[[Path], np.ndarray]]] = {
    "z.ply": (PlyStream, _x_ply),
    "z.las": (LasStream, _x_las),
    "z.laz": (LasStream, _x_las),
    "z.copc.laz": (CopcStream, _x_las),
    "z.e57": (E57Stream, _x_e57),
}


@pytest.mark.parametrize("name", list(WRITERS))
def test_two_writers_of_one_cloud_at_once_each_leave_their_whole_cloud(
    tmp_path: Path, name: str
) -> None:
    """Two writers interleaved part by part, and a third one's temporary in flight at the
    name all writers once shared (``NAME.tmp``, as a COPC writes its file only when it
    closes): left alone."""
    make, read_x = WRITERS[name]
    out = tmp_path / name
    third = tmp_path / f"{name}.tmp"
    third.write_bytes(b"a third writer's half-written cloud")
    first, second = _points(300, 1), _points(200, 2)
    a, b = make(out), make(out)
    a.write(*first)
    b.write(*second)
    a.write(*first)
    a.close()
    np.testing.assert_allclose(read_x(out), np.concatenate([first[0][:, 0]] * 2), atol=1e-3)
    b.close()
    np.testing.assert_allclose(read_x(out), second[0][:, 0], atol=1e-3)
    assert third.read_bytes() == b"a third writer's half-written cloud"
    assert sorted(tmp_path.iterdir()) == [out, third]  # no temporary of theirs left


def test_a_calibration_saved_leaves_another_writers_temporary_alone(tmp_path: Path) -> None:
    """Another process saving the same calibration has its temporary beside it, half
    written; this save neither writes into it nor renames it away."""
    out = tmp_path / "calib.yaml"
    theirs = tmp_path / "calib.yaml.tmp"  # the fixed name all writers once shared
    theirs.write_text("version: 1\nlaser: their half-")
    ours = calibfile.Calibration("front")
    calibfile.save(ours, out)
    assert theirs.read_text() == "version: 1\nlaser: their half-"
    assert out.read_text() == calibfile.dump(ours)
    assert sorted(q.name for q in tmp_path.iterdir()) == ["calib.yaml", "calib.yaml.tmp"]
