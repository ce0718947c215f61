"""The ``corpuscle`` console script's entry point.

Importing the command line (NumPy, the scene kinds, the viewers' modules) takes a second or
more on a loaded machine; Ctrl-C in that time raised KeyboardInterrupt out of the import in
the generated script, a traceback. The import is done here, where it can be caught."""

from __future__ import annotations

import sys


def main() -> int:
    try:
        from .cli import main as cli_main
    except KeyboardInterrupt:
        sys.stderr.write("corpuscle: interrupted\n")
        return 130
    return cli_main()
