"""``corpuscle export``: a recorded run in other formats; its options and handler live with the code that does it,
:mod:`corpuscle.export` (which imports its heavy libraries only when it runs)."""

from __future__ import annotations

from .. import export as _export
from ._options import Command, register

register(Command("export", _export.HELP, _export.configure_parser, _export.run_command, _export.DESCRIPTION))
