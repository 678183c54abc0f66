"""argparse value types for the commands' numeric options: a finite number in a range.

Every numeric option of every command takes one of these as its ``type``, so a bad value
(text that is no number, NaN, an infinity, out of range) is refused while the command line
is parsed, as one line naming the option and its range (``acq colorize: argument --chunk:
expected seconds in [1, 600], got 'nan'``), exit status 2, before anything runs.
"""

from __future__ import annotations

import argparse
import math

__all__ = [
    "LONGEST_S",
    "SEED",
    "Number",
    "integer",
    "real",
]

LONGEST_S = 365 * 86400.0  # a year: the longest span a time option may name, s


class Number:
    """A number of ``kind`` (int or float) between ``lo`` and ``hi`` (inclusive, or not
    with ``lo_open``/``hi_open``), finite; ``what`` names it in the error (``seconds``);
    ``words``: texts taken as they are (``auto``). Called with the option's text, as
    argparse does; :meth:`contains` says whether a parsed value is in the range."""

    def __init__(
        self,
        kind: type[int] | type[float],
        lo: float,
        hi: float,
        *,
        lo_open: bool = False,
        hi_open: bool = False,
        what: str = "",
        words: tuple[str, ...] = (),
    ) -> None:
        self.kind: type[int] | type[float] = kind
        self.lo, self.hi = lo, hi
        self.lo_open, self.hi_open = lo_open, hi_open
        self.what = what or ("an integer" if kind is int else "a number")
        self.words = words
        self.__name__ = self.what  # argparse names a type by it in some messages

    def range_text(self) -> str:
        """The range as the error line and --help give it: ``(0, 3600]``."""
        lo, hi = _shown(self.lo), _shown(self.hi)
        return f"{'(' if self.lo_open else '['}{lo}, {hi}{')' if self.hi_open else ']'}"

    def contains(self, x: object) -> bool:
        """Whether ``x`` is a value this type may give (one of its words, or in range)."""
        if isinstance(x, str):
            return x in self.words
        if not isinstance(x, self.kind) or isinstance(x, bool):
            return False
        if isinstance(x, float) and not math.isfinite(x):
            return False
        above = x > self.lo if self.lo_open else x >= self.lo
        below = x < self.hi if self.hi_open else x <= self.hi
        return above and below

    def __call__(self, text: str) -> float | str:
        word = text.strip()
        if word in self.words:
            return word
        try:
            x: float = self.kind(text)
        except ValueError:  # not a number, or an integer too long to read
            raise self._refused(text) from None
        if not self.contains(x):
            raise self._refused(text)
        return x + 0  # -0.0 is 0.0

    def _refused(self, text: str) -> argparse.ArgumentTypeError:
        either = "".join(f" or {w!r}" for w in self.words)
        shown = text if len(text) <= 40 else text[:37] + "..."
        return argparse.ArgumentTypeError(
            f"expected {self.what} in {self.range_text()}{either}, got {shown!r}"
        )

    def __repr__(self) -> str:  # argparse's "invalid <type> value" never shows it
        return f"{self.what} in {self.range_text()}"


def _shown(x: float) -> str:
    """A bound as people write it: 1000000, 0.01, 4294967295."""
    return str(int(x)) if float(x).is_integer() and abs(x) < 1e16 else f"{x:g}"


def real(
    lo: float,
    hi: float,
    *,
    lo_open: bool = False,
    hi_open: bool = False,
    what: str = "",
    words: tuple[str, ...] = (),
) -> Number:
    """A finite float in the range (see :class:`Number`)."""
    return Number(
        float, float(lo), float(hi), lo_open=lo_open, hi_open=hi_open, what=what, words=words
    )


def integer(lo: int, hi: int, *, what: str = "") -> Number:
    """An int in [lo, hi] (see :class:`Number`)."""
    return Number(int, lo, hi, what=what)


SEED = integer(0, 2**32 - 1, what="a seed")  # what numpy's generators take
