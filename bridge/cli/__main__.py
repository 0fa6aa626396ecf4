"""``python -m bridge.cli``: the ``hitch`` command."""

import sys

from bridge.cli import main  # Ctrl-C while it loads: a line and status 130, not a traceback

sys.exit(main())
