"""The octree of a COPC file (:mod:`acq.cloud.copc`), built out of core: the points
wait on disk as raw LAS point records in scratch files, so that the memory it takes
does not grow with the cloud.

The octree is a cube around the cloud; each node keeps at most :data:`NODE_POINTS`
points drawn at random from those of its cell not kept by a coarser level, in the
order they were written within the node; a cell with no more than that is a leaf, and
the cells of level :data:`MAX_DEPTH` keep whatever is left. A cell holding at most
:data:`BUDGET` points is built in memory (:func:`octree`); a bigger one keeps its random
sample and streams the rest of its scratch file into its children's in one pass, each
built in turn (:func:`build`). The random draws are seeded by the node's key: the same
file every run.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

from acq.atomic_write import discard, temporary_beside

__all__ = [
    "BUDGET", "MAX_DEPTH", "NODE_POINTS", "Cube", "Key", "Scratch", "build", "drop_all",
    "octree",
]  # fmt: skip

NODE_POINTS = 50_000  # points per octree node at most
MAX_DEPTH = 20  # the finest level: whatever is left goes there
BUDGET = 1_000_000  # points of a cell built in memory (~250 bytes each while built)
_READ = 1 << 18  # records read from a scratch file at a time

Key = tuple[int, int, int, int]  # (level, i, j, k)


class Cube:
    """The octree's cube: corner ``lo`` (3,) m and edge ``size`` m, over records whose
    integer coordinates are ``offsets`` + ``scale`` times X, Y, Z (m)."""

    def __init__(self, lo: np.ndarray, size: float, offsets: np.ndarray, scale: float) -> None:
        self.lo, self.size, self.offsets, self.scale = lo, size, offsets, scale

    def xyz(self, records: np.ndarray) -> np.ndarray:
        """The records' coordinates (N,3), m."""
        return np.stack(
            [records[name] * self.scale + self.offsets[k] for k, name in enumerate("XYZ")], axis=1
        )

    def cells(self, xyz: np.ndarray, level: int, within: Key) -> np.ndarray:
        """The (N,3) indices at ``level`` of the cells holding ``xyz``, within the cell
        ``within`` (of a level no finer): a point on its border, or a hair outside by
        rounding, stays in it."""
        top, *ijk = within
        sub = 1 << (level - top)
        base = np.array(ijk, np.int64) * sub
        cell = np.floor((xyz - self.lo) / (self.size / (1 << level))).astype(np.int64)
        clipped: np.ndarray = np.clip(cell, base, base + sub - 1)
        return clipped


class Scratch:
    """Raw point records of ``dtype`` in a temporary file beside ``beside`` (named by
    :func:`acq.atomic_write.temporary_beside`), appended, then read back in order.
    ``made``: the writer's scratch files not yet dropped, this one added: what
    :func:`drop_all` removes when the writer fails."""

    def __init__(self, beside: Path, dtype: np.dtype, made: set[Scratch]) -> None:
        self.path = temporary_beside(beside)  # as any temporary of the output: cleaned alike
        self.dtype = dtype
        self.count = 0
        self._made = made
        self._file = open(self.path, "wb")  # created and locked: closed by close or drop
        made.add(self)

    def append(self, records: np.ndarray) -> None:
        """Append ``records`` (of ``dtype``)."""
        self._file.write(records.tobytes())
        self.count += records.size

    def close(self) -> None:
        """Done appending."""
        self._file.close()

    def chunks(self) -> Iterator[np.ndarray]:
        """The records, in order, :data:`_READ` at a time."""
        with open(self.path, "rb") as f:
            while True:
                part = np.fromfile(f, self.dtype, _READ)
                if part.size == 0:
                    return
                yield part

    def read(self) -> np.ndarray:
        """All the records."""
        return np.fromfile(self.path, self.dtype)

    def drop(self) -> None:
        """Close and remove the file (what it could not flush, on a full disk, dropped)."""
        try:
            self._file.close()
        except OSError:
            pass
        finally:
            discard(self.path)
            self._made.discard(self)


Emit = Callable[[Key, np.ndarray], None]  # a node's key and its records, in order


def build(key: Key, scratch: Scratch, cube: Cube, emit: Emit, spawn: Callable[[], Scratch]) -> None:
    """Emit the nodes of the subtree at ``key`` over the records of ``scratch`` (its cell's
    points not kept by a coarser level; dropped once read); ``spawn`` makes the scratch
    file of a child cell (module docstring)."""
    level = key[0]
    if scratch.count <= BUDGET or level >= MAX_DEPTH:
        records = scratch.read()
        scratch.drop()
        for node, idx in octree(cube.xyz(records), cube, key):
            emit(node, records[idx])
        return
    rng = np.random.default_rng(list(key))
    at = np.sort(rng.choice(scratch.count, min(NODE_POINTS, scratch.count), replace=False))
    children = _split(scratch, at, cube, key, spawn, emit)
    del at  # nothing of this level is held while its children are built
    scratch.drop()
    for ijk, child in sorted(children.items()):
        build((level + 1, *ijk), child, cube, emit, spawn)


def _split(
    scratch: Scratch, at: np.ndarray, cube: Cube, key: Key, spawn: Callable[[], Scratch],
    emit: Emit,
) -> dict[tuple[int, int, int], Scratch]:  # fmt: skip
    """Emit the records of ``scratch`` at the indices ``at`` (sorted) as the node ``key``;
    stream the others into the scratch files of the children of its cell they lie in;
    those files, by the children's (i, j, k)."""
    children: dict[tuple[int, int, int], Scratch] = {}
    kept: list[np.ndarray] = []
    start = 0
    for part in scratch.chunks():
        end = start + part.size
        lo, hi = np.searchsorted(at, [start, end])
        rest = np.ones(part.size, bool)
        rest[at[lo:hi] - start] = False
        kept.append(part[~rest])
        part = part[rest]
        start = end
        cell = cube.cells(cube.xyz(part), key[0] + 1, key)
        octant = (cell[:, 0] & 1) * 4 + (cell[:, 1] & 1) * 2 + (cell[:, 2] & 1)
        for o in np.unique(octant).tolist():
            i, j, k = (int(v) for v in cell[np.argmax(octant == o)])
            child = children.get((i, j, k))
            if child is None:
                child = children[i, j, k] = spawn()
            child.append(part[octant == o])
    for child in children.values():
        child.close()
    emit(key, np.concatenate(kept))
    return children


def octree(xyz: np.ndarray, cube: Cube, root: Key = (0, 0, 0, 0)) -> list[tuple[Key, np.ndarray]]:
    """The nodes (key, indices into ``xyz`` in order) of the subtree at ``root`` over the
    points ``xyz`` (N,3) m of its cell, in memory (module docstring)."""
    top = root[0]
    left = np.random.default_rng(list(root)).permutation(xyz.shape[0])
    nodes: list[tuple[Key, np.ndarray]] = []
    level = top
    while left.size:
        ijk = cube.cells(xyz[left], level, root)
        side = 1 << (level - top)
        rel = ijk - np.array(root[1:], np.int64) * side
        key = (rel[:, 0] * side + rel[:, 1]) * side + rel[:, 2]
        order = np.argsort(key, kind="stable")  # random within a cell: left is shuffled
        key, left, ijk = key[order], left[order], ijk[order]
        starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
        rank = np.arange(key.size) - np.repeat(starts, np.diff(np.r_[starts, key.size]))
        take = rank < NODE_POINTS if level < MAX_DEPTH else np.ones(key.size, bool)
        ends = np.r_[starts[1:], key.size]
        for a, b in zip(starts.tolist(), ends.tolist(), strict=True):
            kept = left[a:b][take[a:b]]
            i, j, k = (int(v) for v in ijk[a])
            nodes.append(((level, i, j, k), np.sort(kept)))
        left = left[~take]
        level += 1
    return nodes


def drop_all(made: set[Scratch]) -> None:
    """Drop every scratch file in ``made``."""
    for scratch in list(made):
        scratch.drop()
