"""Which of a log's cameras a command works on: the names asked for (``--camera``), the
log's and the calibration's, matched in one place so that every command says the same.

A calibration of one camera pairs with a log of one camera whatever their names (a
calib.yaml made for ``camera`` colours a log whose camera is ``front``); otherwise a
camera is used by its name, which must be in both.
"""

from __future__ import annotations

from collections.abc import Sequence

from acq.errors import InputValueError

__all__ = ["CameraChoiceError", "choose_cameras", "named_once"]


class CameraChoiceError(InputValueError):
    """No camera, a camera that is not in the log or the calibration, one named twice,
    or several where one is needed; the message lists the names found (exit status 2)."""


def _listed(names: Sequence[str]) -> str:
    return ", ".join(names) if names else "none"


def named_once(asked: Sequence[str]) -> list[str]:
    """The names given with ``--camera``; :class:`CameraChoiceError` naming one given
    twice (a slip, another camera meant perhaps: said, not merged)."""
    twice = next((n for k, n in enumerate(asked) if n in asked[:k]), None)
    if twice is not None:
        raise CameraChoiceError(f"--camera {twice}: named twice; give each camera once")
    return list(asked)


def choose_cameras(
    asked: Sequence[str] | None,
    in_log: Sequence[str],
    in_calib: Sequence[str],
    *,
    one: bool,
    calib: str = "the calibration",
) -> list[tuple[str, str]]:
    """(name in the log, name in the calibration) of each camera to work on.

    ``asked``: the names given with ``--camera``, each once (None or empty: choose);
    ``in_log``: the cameras the log has frames of; ``in_calib``: the calibration's;
    ``one``: the command works on one camera (several found is then an error unless one
    is asked for); ``calib`` names the calibration file in messages. Unasked, every
    camera in both (or the only one of each). Raises :class:`CameraChoiceError` naming the option
    and listing the log's and the calibration's names, saying which do not match.
    """
    log_names, calib_names = sorted(in_log), list(in_calib)
    found = f"the log has {_listed(log_names)}; {calib} has {_listed(calib_names)}"
    if asked:
        wanted = named_once(asked)
        if one and len(wanted) > 1:
            raise CameraChoiceError(f"--camera: give one camera, not {_listed(wanted)}")
        for name in wanted:
            missing = [
                where
                for where, names in (("the log", log_names), (calib, calib_names))
                if name not in names
            ]
            if missing:
                where = " nor ".join(missing)
                raise CameraChoiceError(
                    f"--camera {name}: {'in neither' if len(missing) > 1 else 'not in'} "
                    f"{where} ({found})"
                )
        return [(n, n) for n in wanted]
    if not log_names:
        raise CameraChoiceError("the log has no camera frames (no /<name>/image/compressed)")
    if not calib_names:
        raise CameraChoiceError(f"{calib} has no camera")
    if len(log_names) == 1 and len(calib_names) == 1:
        return [(log_names[0], calib_names[0])]
    both = [n for n in calib_names if n in log_names]  # in the calibration's order
    if not both:
        raise CameraChoiceError(
            f"the log's camera names and {calib}'s do not match ({found}); rename the "
            f"cameras in {calib} to the log's names"
        )
    if one and len(both) > 1:
        raise CameraChoiceError(
            f"the log has several cameras ({_listed(log_names)}); name one with --camera "
            f"({calib} has {_listed(calib_names)})"
        )
    return [(n, n) for n in both]
