"""What ``acq colorize`` keeps of the chunks it has written (:class:`Tally`): counts for
the report, the frames used, the colour gains, and what the preview draws of the points
(thinned for a long drive), so that nothing else of the cloud is held."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from acq.cloud.chunks import ChunkResult
from acq.cloud.points import Cloud

__all__ = ["PREVIEW_FIELDS", "Tally"]

# the per-point fields the preview draws (acq.cloud.preview); the others are not held
PREVIEW_FIELDS = ("xyz", "rgb", "coloured", "camera", "scan", "step")


@dataclass
class Tally:
    """What the report and the preview keep of the chunks written: counts, the frames
    used, and every ``every``-th scan's points for the preview (0: none)."""

    every: int
    points: int = 0
    coloured: int = 0
    hidden: int = 0
    outside: int = 0
    used: list[np.ndarray] = field(default_factory=list)
    by_camera: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    gains: list[list[np.ndarray]] = field(default_factory=list)  # per chunk, per camera
    pairs: list[tuple[int, ...]] = field(default_factory=list)  # per chunk, per camera
    pair_total: int = 0
    seconds: dict[str, float] = field(default_factory=dict)
    preview: list[dict[str, np.ndarray]] = field(default_factory=list)  # per chunk, by field
    # by camera: stamp -> (w, h)
    odd_size: dict[str, dict[int, tuple[int, int]]] = field(default_factory=dict)
    undecodable: dict[str, set[int]] = field(default_factory=dict)  # by camera: stamps

    def add(self, r: ChunkResult) -> None:
        self.points += r.time_ns.size
        for name, odd in r.odd_size.items():
            self.odd_size.setdefault(name, {}).update(odd)
        for name, bad in r.undecodable.items():
            self.undecodable.setdefault(name, set()).update(bad)
        self.coloured += int(np.count_nonzero(r.coloured))
        counts = np.bincount(r.camera[r.coloured], minlength=self.by_camera.size)
        if counts.size > self.by_camera.size:
            counts[: self.by_camera.size] += self.by_camera
            self.by_camera = counts
        else:
            self.by_camera = self.by_camera + counts
        if r.gains is not None:
            self.gains.append([np.exp(g) for g in r.gains.log_gain])
            self.pairs.append(r.gains.by_camera)
            self.pair_total += r.gains.pairs
        self.hidden += int(np.count_nonzero(r.hidden))
        self.outside += r.outside
        if r.used_stamps is not None:
            self.used.append(r.used_stamps)
        for key, v in r.seconds.items():
            self.seconds[key] = self.seconds.get(key, 0.0) + v
        if self.every > 0:  # every == 1: the arrays themselves, no copies
            k = slice(None) if self.every == 1 else r.scan % self.every == 0
            kept = {name: getattr(r, name)[k] for name in PREVIEW_FIELDS}
            self.preview.append({**kept, "scan_origin": r.scan_origin})

    def preview_cloud(self, clock: np.ndarray, cameras: Sequence[str]) -> Cloud:
        """The points kept for the preview as a :class:`Cloud` (of the log's ``clock``
        pairs, coloured from ``cameras``), the chunks' parts let go field by field as
        they are joined; the fields the preview does not draw are zeros that take no
        memory."""
        empty = {"xyz": np.zeros((0, 3)), "rgb": np.zeros((0, 3), np.uint8),
                 "coloured": np.zeros(0, bool), "camera": np.zeros(0, np.uint8),
                 "scan": np.zeros(0, np.uint32), "step": np.zeros(0, np.uint32),
                 "scan_origin": np.zeros((0, 3))}  # fmt: skip
        fields: dict[str, Any] = {}
        for name in (*PREVIEW_FIELDS, "scan_origin"):
            fields[name] = np.concatenate([empty[name], *(p.pop(name) for p in self.preview)])
        self.preview = []
        n = fields["xyz"].shape[0]
        for name, dtype in (("time_ns", np.int64), ("intensity", np.float32),
                            ("dt_s", np.float32), ("frame", np.int32)):  # fmt: skip
            fields[name] = np.broadcast_to(np.zeros(1, dtype), (n,))
        return Cloud(
            **fields,
            view_axis=np.array([0.0, 1.0, 0.0]),
            clock=clock,
            camera_names=tuple(cameras),
        )

    def balance_summary(self, names: Sequence[str], applied: bool) -> dict[str, Any]:
        """What the report says of the colour balance (:class:`Report`'s ``balance``)."""
        if not applied:
            return {"applied": False}
        cams: dict[str, Any] = {}
        for c, name in enumerate(names):
            g = [chunk[c] for chunk in self.gains if c < len(chunk) and chunk[c].size]
            entry: dict[str, Any] = {"pairs": sum(p[c] for p in self.pairs if c < len(p))}
            if g:
                all_g = np.concatenate(g)
                for k, ch in enumerate("rgb"):
                    q = np.percentile(all_g[:, k], [0, 50, 100])
                    entry[ch] = [round(float(v), 3) for v in q]
            cams[name] = entry
        return {"applied": True, "pairs": self.pair_total, "cameras": cams}
