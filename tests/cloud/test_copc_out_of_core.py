"""A COPC file's octree built out of core (acq.cloud.octree): the points wait in scratch
files beside the output, so the writer's memory does not grow with the drive (it held
the whole cloud until close: 3.55 GB for 5 minutes of drive). The files are read back
with copclib's and laspy's readers."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import laspy
import numpy as np
import pytest

from acq.cloud import octree
from acq.cloud.copc import CopcStream
from acq.errors import AcqError
from acq.sim.long_cloud import parts


def test_an_octree_built_out_of_core_holds_every_point_once_in_valid_nodes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Cells over 3,000 points spill to their children's scratch files (several levels
    deep here): every point is in exactly one node, each node in its cell, under its
    parent, with at most NODE_POINTS points (exactly that many where it has children),
    in time order; no scratch file is left."""
    monkeypatch.setattr(octree, "BUDGET", 3000)
    monkeypatch.setattr(octree, "NODE_POINTS", 400)
    monkeypatch.setattr(octree, "_READ", 5000)  # several reads per scratch file
    drive = list(parts(1.2, part_s=0.2))
    out = tmp_path / "c.copc.laz"
    stream = CopcStream(out, cameras=["left", "right"])
    for p in drive:
        stream.write(*p)
    stream.close()
    assert list(tmp_path.iterdir()) == [out]
    n = sum(p[0].shape[0] for p in drive)
    utc = np.concatenate([p[2] for p in drive])
    xyz = np.concatenate([p[0] for p in drive])

    with laspy.CopcReader.open(out) as r:  # copclib's reader refuses named extra bytes
        assert r.header.point_count == len(r.query()) == n
        nodes = {(k.key.level, k.key.x, k.key.y, k.key.z): k for k in _nodes(r)}
        with_children = {(d - 1, x // 2, y // 2, z // 2) for d, x, y, z in nodes if d > 0}
        assert with_children <= set(nodes)  # every node's parent is there
        assert max(d for d, *_ in nodes) >= 4
        got = []
        for key, node in nodes.items():
            points = r._fetch_and_decompress_points_of_nodes([node])
            assert len(points) == node.point_count > 0
            assert len(points) == 400 if key in with_children else len(points) <= 400
            assert np.all(np.diff(points.gps_time) > 0)  # time order within a node
            box = np.stack([points.x, points.y, points.z], axis=1)
            assert np.all(box >= node.bounds.mins - 1e-3) and np.all(box <= node.bounds.maxs + 1e-3)
            got.append(box[np.argsort(points.gps_time)])
            got_t = np.asarray(points.gps_time)
            got.append(got_t)
    every = np.concatenate(got[::2])
    t = np.concatenate(got[1::2])
    assert every.shape[0] == n
    back = every[np.argsort(t, kind="stable")]
    assert np.abs(back - xyz[np.argsort(utc)]).max() <= 0.0005 + 1e-9  # each point once


def _nodes(r: laspy.CopcReader) -> list:  # type: ignore[type-arg]
    """Every node of the file's hierarchy, as laspy reads it."""
    from laspy.copc import load_octree_for_query

    return load_octree_for_query(r.source, r.copc_info, r.root_page)


def test_an_octree_built_out_of_core_is_the_same_every_run(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(octree, "BUDGET", 3000)
    monkeypatch.setattr(octree, "NODE_POINTS", 400)
    files = []
    for name in ("a.copc.laz", "b.copc.laz"):
        stream = CopcStream(tmp_path / name)
        for p in parts(0.6, part_s=0.2):
            stream.write(*p)
        stream.close()
        with laspy.CopcReader.open(tmp_path / name) as r:
            files.append({
                (n.key.level, n.key.x, n.key.y, n.key.z): np.asarray(
                    r._fetch_and_decompress_points_of_nodes([n]).array).tobytes()
                for n in _nodes(r)
            })  # fmt: skip
    assert files[0] == files[1]


# the peaks: VmHWM of the child's own memory (ru_maxrss would count the test process it
# was spawned from, which may be larger than the writer ever gets)
_CHILD = """
import json, sys
from pathlib import Path
from acq.cloud import octree
from acq.cloud.copc import CopcStream
from acq.errors import AcqError
from acq.sim.long_cloud import parts

def peak_kb():
    return next(int(l.split()[1]) for l in open("/proc/self/status") if l.startswith("VmHWM:"))

octree.BUDGET = 150_000
out = CopcStream(Path(sys.argv[1]))
peaks = []
for p in parts(float(sys.argv[2]), part_s=2.0):
    out.write(*p)
    peaks.append(peak_kb())
out.close()
peaks.append(peak_kb())
print(json.dumps(peaks))
"""


def test_the_copc_writers_memory_does_not_grow_with_the_cloud(tmp_path: Path) -> None:
    """1.4 M points (40 s of the demo rig's drive) through a COPC writer in a process of
    its own, cells of over 150,000 points spilled: its peak memory grows by less than
    110 MB after the first part (about 65 MB measured; the writer that held the points
    until close grew by 226 MB)."""
    run = subprocess.run(
        [sys.executable, "-c", _CHILD, str(tmp_path / "c.copc.laz"), "40"],
        capture_output=True, text=True, timeout=300, check=True,
    )  # fmt: skip
    peaks_kb = json.loads(run.stdout)
    growth_mb = (peaks_kb[-1] - peaks_kb[0]) / 1024
    assert growth_mb < 110, f"peak memory grew by {growth_mb:.0f} MB"
    assert [p.name for p in tmp_path.iterdir()] == ["c.copc.laz"]


def test_a_point_beyond_the_files_reach_is_refused_naming_the_output(tmp_path: Path) -> None:
    """The offset is the first part's (the cloud's extent is not known before close): a
    point 3,000 km away cannot be held in 32-bit millimetres, nor a point not finite."""
    out = tmp_path / "c.copc.laz"
    first, far = parts(0.2), parts(0.2, seed=1)
    stream = CopcStream(out)
    stream.write(*next(first))
    xyz, *rest = next(far)
    with pytest.raises(AcqError, match=rf"^{out}: a point lies 3000 km from the cloud's first"):
        stream.write(xyz + np.array([3e6, 0.0, 0.0]), *rest)
    with pytest.raises(AcqError, match=rf"^{out}: a point's coordinates are not finite$"):
        stream.write(np.where(xyz == xyz[0], np.nan, xyz), *rest)
    stream.abort()
    assert list(tmp_path.iterdir()) == []
