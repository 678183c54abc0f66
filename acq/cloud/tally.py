"""What ``acq colorize`` keeps of the chunks it has written (:class:`Tally`): counts for
the report, the frames used, the colour gains, and a thinned copy of the points for the
preview, so that nothing of the cloud itself is held."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from acq.cloud.chunks import PER_POINT, ChunkResult

__all__ = ["Tally"]


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
    preview: list[ChunkResult] = field(default_factory=list)
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
        if self.every == 1:
            self.preview.append(r)
        elif self.every > 1:
            k = r.scan % self.every == 0
            thin = {name: getattr(r, name)[k] for name in PER_POINT}
            self.preview.append(replace(r, **thin, uv=None, frame_stamp_ns=None, samples=None))

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
