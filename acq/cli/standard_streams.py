"""The standard streams of a process started with one of them closed.

Run with a standard descriptor closed (``acq record >&-``), Python sets ``sys.stdout``
(or ``stdin``, ``stderr``) to None, and the first file the process opens takes the free
descriptor: a recording's MCAP file would become descriptor 1, and whatever a library or
a child process writes to stdout would go into it. :func:`reopen_closed` opens
``/dev/null`` on each closed one of descriptors 0, 1 and 2 before anything else is
opened, as daemons do, and gives Python a stream on it: what would have been printed is
dropped, and nothing else lands there.
"""

from __future__ import annotations

import os
import sys

__all__ = ["reopen_closed"]

_STREAMS = (("stdin", os.O_RDONLY, "r"), ("stdout", os.O_WRONLY, "w"), ("stderr", os.O_WRONLY, "w"))


def reopen_closed() -> None:
    """Descriptors 0, 1 and 2 open (on ``/dev/null`` those that were closed) and
    ``sys.stdin``, ``sys.stdout``, ``sys.stderr`` streams (on ``/dev/null`` those that
    were None)."""
    for fd, (name, flags, mode) in enumerate(_STREAMS):
        try:
            os.fstat(fd)
        except OSError:  # closed: /dev/null takes its place
            devnull = os.open(os.devnull, flags)
            if devnull != fd:
                os.dup2(devnull, fd)  # inheritable, as a standard descriptor is
                os.close(devnull)
            else:
                os.set_inheritable(fd, True)
            if getattr(sys, name) is None:
                setattr(sys, name, open(fd, mode, closefd=False))
        else:
            if getattr(sys, name) is None:  # its descriptor is another file's now
                setattr(sys, name, open(os.devnull, mode))
