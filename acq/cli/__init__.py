"""The `acq` command line: one module per command, each adding its sub-parser and holding
its handler (parse, call the library, print); :mod:`acq.cli.main` holds the root and maps
errors to exit statuses."""

import os

# The commands run their own threads (a camera each, a chunk each): OpenBLAS's own pool
# on top of them, woken by the small products of points and rotations, waits for work by
# yielding on the cores those threads need (0.5 s of the check of a 60 s drive). One BLAS
# thread, unless the user says otherwise; set before numpy loads OpenBLAS.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from acq.cli.main import build_parser, main

__all__ = ["build_parser", "main"]
