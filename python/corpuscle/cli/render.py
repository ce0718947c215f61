"""``corpuscle render``: pictures and videos of a recorded run; its options and handler live with the code that does it,
:mod:`corpuscle.render` (which imports its heavy libraries only when it runs)."""

from __future__ import annotations

from .. import render as _render
from ._options import Command, register

register(Command("render", _render.HELP, _render.configure_parser, _render.run_command, _render.DESCRIPTION))
