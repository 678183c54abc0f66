"""A log's fixes read back as arrays (acq/log/vehicle_log.py): each fix once, two fixes
the recorder stamped alike both kept, a fix read twice (a file given twice) once."""

from __future__ import annotations

import math

import numpy as np

from acq.log.vehicle_log import _fixes


def _row(t_ns: int, utc_s: float, lat: float) -> tuple[object, ...]:
    """A fix as read from a log: stamp, UTC, position, quality, hdop, satellites, motion."""
    return (t_ns, utc_s, lat, 2.29, 81.5, 1, 0.7, 14, 5.6, math.nan)


def test_fixes_stamped_alike_are_both_kept_and_a_repeated_one_once() -> None:
    # the first fixes held up by a loaded host: the clock's envelope then dropped by a
    # period, and the second got the first's stamp
    rows = [_row(1_000, 100.0, 48.0), _row(1_000, 100.1, 48.1), _row(1_100, 100.2, 48.2)]
    f = _fixes(rows + rows[1:2])  # the second fix read twice (a file given twice)
    assert f.t_ns.tolist() == [1_000, 1_000, 1_100]
    assert f.utc_s.tolist() == [100.0, 100.1, 100.2]
    assert np.array_equal(f.lat, [48.0, 48.1, 48.2])
