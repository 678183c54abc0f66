"""The `acq` command line: one module per command, each adding its sub-parser and holding
its handler (parse, call the library, print); :mod:`acq.cli.main` holds the root and maps
errors to exit statuses."""

from acq.cli.main import build_parser, main

__all__ = ["build_parser", "main"]
