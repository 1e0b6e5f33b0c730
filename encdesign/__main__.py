"""``python -m encdesign``: the ``encdesign`` command."""

import sys

from .cli import main

sys.exit(main())
