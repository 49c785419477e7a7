"""``python -m ringtrack.tools.cli ARGS``: the ``ringtrack`` command (how spawn starts role processes)."""

import sys

from ringtrack.tools.cli import main

sys.exit(main())
