"""A :class:`acq.monitor.snapshot.Snapshot` for people (a rich renderable: a full-screen
view, or printed once as plain text) and for scripts (:func:`as_json`)."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

from rich.console import Group, RenderableType
from rich.table import Table
from rich.text import Text

from acq.log.schemas import ColouringStatus
from acq.monitor.snapshot import Snapshot, problems

__all__ = ["as_json", "render"]


def render(snap: Snapshot, stale_s: float) -> Group:
    """The snapshot as a header, one table row per device and its problems."""
    if snap.writing:
        state = "recording"
        if snap.status_age_s is not None:
            state += f", status {snap.status_age_s:.1f} s old"
    elif snap.closed:
        state = "finished, not being written: its last state"
    else:
        state = "not being written, not closed (its recorder stopped): its last state"
    size = "" if snap.file_bytes is None else f", {snap.file_bytes / 1e6:.1f} MB"
    if not snap.source.startswith("log "):  # the recorder's file name, and where from
        size += f" ({snap.source})"
    head = Text.assemble(("acq status", "bold"), f"  {snap.file or '-'}{size}  ", (state, "cyan"))
    lines: list[RenderableType] = [head]
    facts = []
    if snap.uptime_s is not None:
        facts.append(f"up {snap.uptime_s:.0f} s")
    if snap.write_rate_bps is not None:
        facts.append(f"writing {snap.write_rate_bps / 1e6:.2f} MB/s")
    if snap.disk_free_bytes is not None:
        facts.append(f"disk {snap.disk_free_bytes / 1e9:.1f} GB free")
    if math.isfinite(snap.disk_minutes_left):
        facts.append(f"{snap.disk_minutes_left:.0f} min left above the reserve")
    if facts:
        lines.append(Text(", ".join(facts)))
    lines.append(Text(f"time base: {snap.time_base or 'no /acq/timebase reading yet'}"))
    if snap.colouring is not None:
        lines.append(_colouring(snap.colouring))
    table = Table(expand=False)
    widest = max((len(d.name) + 2 for d in snap.devices), default=6)
    table.add_column("device", no_wrap=True, min_width=widest)
    table.add_column("kind", no_wrap=True, min_width=14)
    for name in ("rate Hz", "drops", "gap s", "clock ±ms", "drift ppm"):
        table.add_column(name, justify="right", no_wrap=True, min_width=len(name))
    # the one column that gives way on a narrow terminal
    table.add_column("last event", no_wrap=True, overflow="ellipsis", max_width=44)
    for d in snap.devices:
        gap_style = "red" if d.gap_s > stale_s or not d.connected else ""
        name = d.name + (" *" if d.required else "")
        # a device the host stamps on receipt (a camera, the CAN bus) has no clock to sync
        clockless = not (d.clock_offset_ms or d.clock_drift_ppm or d.clock_uncertainty_s)
        sync, drift = ("-", "-") if clockless else (
            "?" if math.isnan(d.clock_uncertainty_s) else f"{d.clock_uncertainty_s * 1e3:.2f}",
            f"{d.clock_drift_ppm:+.1f}",
        )  # fmt: skip
        table.add_row(
            name,
            d.kind + ("" if d.connected else " (down)"),
            f"{d.rate_hz:.1f}",
            str(d.dropped),
            Text(f"{d.gap_s:.1f}", style=gap_style),
            sync,
            drift,
            d.last_event or "",
        )
    if snap.devices:
        lines.append(table)
        if any(d.required for d in snap.devices):
            lines.append(Text("* required"))
    else:
        lines.append(Text("no /acq/status from the recorder yet"))
    for p in problems(snap, stale_s):
        lines.append(Text(f"! {p}", style="bold red"))
    lines += [Text(n, style="yellow") for n in snap.notes]
    return Group(*lines)


def _colouring(c: ColouringStatus) -> Text:
    """The live colouring's line: shares of the last scans' points, scans skipped."""
    cameras = ", ".join(f"{name} {share:.0%}" for name, share in c.camera_shares.items())
    return Text.assemble(
        f"colouring: {c.coloured_share:.0%} of the last scans' points"
        + (f" ({cameras})" if cameras else "")
        + f"; {c.scans_coloured} scans coloured, ",
        (f"{c.scans_skipped} skipped (fell behind)", "yellow" if c.scans_skipped else ""),
    )


def as_json(snap: Snapshot, stale_s: float) -> dict[str, Any]:
    """The snapshot as plain data, with its problems (``ok``: none). What is not known
    is null: ``disk_minutes_left`` when nothing is being written, a device's
    ``clock_uncertainty_s`` before its clock sync has one. ``colouring`` only when the
    recorder colours live."""
    found = problems(snap, stale_s)
    out = dataclasses.asdict(snap)
    if snap.colouring is None:
        del out["colouring"]
    out["disk_minutes_left"] = _known(snap.disk_minutes_left)
    for d in out["devices"]:
        d["clock_uncertainty_s"] = _known(d["clock_uncertainty_s"])
    return {**out, "stale_s": stale_s, "ok": not found, "problems": found}


def _known(x: float) -> float | None:
    return x if math.isfinite(x) else None
