"""``--camera NAME``, the same option on every command that works per camera.

The name is the camera's in the log (``/NAME/image/compressed``) and in the calibration
(``cameras: NAME:``); :func:`acq.camera.selection.choose_cameras` matches them and,
when a name is missing or wrong, lists the log's and the calibration's names.
"""

from __future__ import annotations

import argparse

__all__ = ["add_camera_option"]


class _OneCamera(argparse.Action):
    """``--camera`` of a command that works on one camera: a second one is refused
    (argparse's ``store`` would keep the last silently)."""

    def __call__(
        self, parser: argparse.ArgumentParser, namespace: argparse.Namespace,
        values: object, option_string: str | None = None,
    ) -> None:  # fmt: skip
        before = getattr(namespace, self.dest, None)
        if before is not None:
            raise argparse.ArgumentError(
                self,
                f"given twice ({before}, {values}): this command works on one "
                "camera; run it once for each",
            )
        setattr(namespace, self.dest, values)


def add_camera_option(
    parser: argparse.ArgumentParser,
    use: str,
    *,
    several: bool = False,
    default: str | None = None,
    named: str = "by its name in the log and the calibration",
) -> None:
    """Add ``--camera NAME`` to ``parser``: ``use`` says what the command does with it
    ("the camera to validate"); ``several``: repeatable, a list of names; ``default``
    replaces the help's default (unset: every camera, or the only one, that both the log
    and the calibration have); ``named`` says where the names come from."""
    if default is None:
        default = (
            "every camera that both the log and the calibration have"
            if several
            else "the only camera that both the log and the calibration have"
        )
    repeat = "; repeat for several" if several else ""
    parser.add_argument(
        "--camera",
        metavar="NAME",
        action="append" if several else _OneCamera,
        help=f"{use}, {named}{repeat} (default: "
        f"{default}); a name that is missing or wrong is refused with the names found",
    )
