"""``python -m ssamb``: see :mod:`ssamb.cli`."""
import sys

from .cli import main

sys.exit(main())
