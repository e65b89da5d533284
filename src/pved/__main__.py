"""``python -m pved`` is the ``pved`` command."""

import sys

from pved.cli import main

sys.exit(main())
