"""``python -m corpuscle.cli`` runs the command line (as the ``corpuscle`` script does)."""

import sys

from . import main

sys.exit(main())
