"""``python -m shadowmap``: the same command line as ``shadowmap``."""

import sys

from .cli import main

sys.exit(main())
