"""``python -m corpuscle`` runs the command line."""

import sys

from ._entry import main

# same exit codes as the console script
sys.exit(main())
