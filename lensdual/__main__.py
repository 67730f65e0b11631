"""``python -m lensdual``: the same as the ``lensdual`` command."""

import sys

from .cli import main

sys.exit(main())
