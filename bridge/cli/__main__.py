"""``python -m bridge.cli``: the ``hitch`` command."""

import sys

from bridge.cli.main import main

sys.exit(main())
