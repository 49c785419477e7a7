"""``python -m ringtrack``: the ``ringtrack`` command."""

import sys

from ringtrack.tools.cli import main

sys.exit(main())
