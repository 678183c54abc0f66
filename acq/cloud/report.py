"""What `acq colorize` did (:class:`Report`), for its text or JSON report."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

__all__ = ["Report"]


@dataclass
class Report:
    """What `acq colorize` did, for the text or JSON report."""

    output: str
    points: int = 0
    coloured: int = 0
    hidden: int = 0
    frames: int = 0
    frames_used: int = 0
    frames_failed: int = 0
    frames_odd_size: int = 0  # of another size than the camera model's: not used
    scans: int = 0
    duration_s: float = 0.0
    frame: str = "world"
    view: str = "nearest"
    trajectory: str = ""
    retiming: dict[str, Any] = field(default_factory=dict)
    time_offset: dict[str, Any] = field(default_factory=dict)
    chunks: int = 0
    bytes: int = 0
    seconds: dict[str, float] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    def lines(self) -> list[str]:
        share = self.coloured / self.points if self.points else 0.0
        rt = self.retiming
        out = [
            f"{self.points:,} points from {self.scans:,} scans ({self.duration_s:.1f} s), "
            f"{100 * share:.1f} % coloured from {self.frames_used:,} of {self.frames:,} frames "
            f"(--view {self.view}); {self.hidden:,} hidden from every candidate frame",
            f"frame: {self.frame}; trajectory: {self.trajectory or 'none'}",
        ]
        if rt:
            out.append(
                f"re-timed offline: scans moved {rt.get('scan_shift_rms_ms', 0):.3f} ms RMS, "
                f"frames {rt.get('frame_residual_rms_ms', 0):.2f} ms RMS receipt jitter removed"
            )
        total = sum(self.seconds.values())
        if total:
            parts = ", ".join(f"{k} {v:.1f} s" for k, v in self.seconds.items())
            speed = self.duration_s / self.seconds.get("total", total) if total else 0.0
            out.append(f"time: {parts} ({speed:.1f}x real time)")
        out += [f"note: {n}" for n in self.notes]
        out.append(f"wrote {self.output}")
        return out
