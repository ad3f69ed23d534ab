"""``python -m scenarios`` is ``vnav-demo``."""

import sys

from scenarios.cli import main

sys.exit(main())
