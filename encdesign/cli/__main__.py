"""``python -m encdesign.cli``: the ``encdesign`` command."""

import sys

from ._main import main

sys.exit(main())
