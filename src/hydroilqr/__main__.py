"""``python -m hydroilqr ...``: the same command line as the ``hydroilqr`` script."""

import sys

from hydroilqr.cli import main

sys.exit(main())
