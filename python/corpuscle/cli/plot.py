"""``corpuscle plot``: plots of a recorded run's quantities; its options and handler live with the code that does it,
:mod:`corpuscle.plot` (which imports its heavy libraries only when it runs)."""

from __future__ import annotations

from .. import plot as _plot
from ._options import Command, register

register(Command("plot", _plot.HELP, _plot.configure_parser, _plot.run_command, _plot.DESCRIPTION))
