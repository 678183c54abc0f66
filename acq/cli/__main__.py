"""``python -m acq.cli``: the same as the ``acq`` command."""

import sys

from acq.cli import main

sys.exit(main())
