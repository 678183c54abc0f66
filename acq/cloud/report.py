"""What `acq colorize` did (:class:`Report`), for its text or JSON report."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

__all__ = ["Report"]


@dataclass
class Report:
    """What `acq colorize` did, for the text or JSON report (plain Python values only:
    the JSON report is ``asdict`` of it).

    ``cameras``: per camera name, ``points`` (int) coloured from it, ``frames_used``
    (int) its frames that coloured at least one point, optionally ``frames`` (int) its
    frames in the log, optionally ``frames_undecodable`` (int) those that do not decode
    (skipped, named in a note). ``balance``: the colour balance between cameras and frames,
    empty when none was computed: ``applied`` (bool, False with ``--no-balance``),
    ``pairs`` (int) point pairs (one point seen by two cameras or frames) the gains
    were fitted on, ``cameras``: per camera name ``pairs`` (int) of them involving it and
    the gains applied to its frames, per channel ``r``, ``g``, ``b`` a [min, median,
    max] list (1.0: unchanged); optionally ``note`` (str). ``calibration_check``: per
    camera name, the check of its calibration on the drive when asked
    (:meth:`acq.calib.pose_check.PoseCheck.to_dict`, and its ``line``).
    """

    output: str
    points: int = 0
    coloured: int = 0
    hidden: int = 0
    frames: int = 0
    frames_used: int = 0
    frames_failed: int = 0  # that do not decode as JPEG: not used
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
    cameras: dict[str, dict[str, Any]] = field(default_factory=dict)
    balance: dict[str, Any] = field(default_factory=dict)
    calibration_check: dict[str, dict[str, Any]] = field(default_factory=dict)
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
        out += self._camera_lines() + self._time_offset_lines() + self._balance_lines()
        out += self.check_lines()
        total = sum(self.seconds.values())
        if total:
            parts = ", ".join(f"{k} {v:.1f} s" for k, v in self.seconds.items())
            speed = self.duration_s / self.seconds.get("total", total) if total else 0.0
            out.append(f"time: {parts} ({speed:.1f}x real time)")
        out += [f"note: {n}" for n in self.notes]
        out.append(f"wrote {self.output}")
        return out

    def check_lines(self) -> list[str]:
        """One line per camera whose calibration was checked: its verdict."""
        return [f"calibration check: {c['line']}" for c in self.calibration_check.values()]

    def _camera_lines(self) -> list[str]:
        """One line per camera: the points coloured from it and the frames it gave."""
        out = []
        for name, c in self.cameras.items():
            n = int(c.get("points", 0))
            share = 100 * n / self.points if self.points else 0.0
            frames = f"{c.get('frames_used', 0):,}"
            if "frames" in c:
                frames += f" of {c['frames']:,}"
            bad = c.get("frames_undecodable", 0)
            why = f" ({bad:,} do not decode: see the note)" if bad else ""
            out.append(f"camera {name}: {n:,} points ({share:.1f} %) from {frames} frames{why}")
        return out

    def _time_offset_lines(self) -> list[str]:
        """--time-offset auto: per camera the offset used (camera minus laser time), with
        its standard error when estimated, else CALIB's and why (the note)."""
        out = []
        for name, c in self.time_offset.get("cameras", {}).items():
            if "found" not in c:  # not estimated: CALIB's or --time-offset S, as given
                continue
            used = f"{1e3 * c.get('used_s', 0.0):+.2f} ms"
            if c["found"]:
                se = c.get("std_s", float("nan"))
                se_text = f" +- {1e3 * se:.2f} ms" if se == se else " (no standard error)"
                out.append(
                    f"time offset {name}: {used}{se_text} (camera minus laser time), estimated "
                    f"from {c.get('frames', 0):,} frames of this log (--time-offset auto)"
                )
            else:
                out.append(f"time offset {name}: {used}, CALIB's: no estimate (see the note)")
        return out

    def _balance_lines(self) -> list[str]:
        """The colour balance: off, or its point pairs and each camera's gains."""
        b = self.balance
        if not b:
            return []
        if not b.get("applied", True):
            head = "colour balance: off (--no-balance)"
            return [head + (f"; {b['note']}" if b.get("note") else "")]
        out = [f"colour balance from {b.get('pairs', 0):,} point pairs (gains min/median/max)"]
        for name, c in b.get("cameras", {}).items():
            gains = "  ".join(
                f"{ch.upper()} " + "/".join(f"{g:.2f}" for g in c[ch]) for ch in "rgb" if ch in c
            )
            out.append(f"  {name}: {gains} ({c.get('pairs', 0):,} pairs)")
        if b.get("note"):
            out.append(f"  {b['note']}")
        return out
