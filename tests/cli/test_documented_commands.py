"""Every documented command must run as printed: each ``corpuscle ...`` command of README.md
and docs/*.md (every one in a code block, those with an option in an inline code span) is parsed by the real argument parser
(``validate NAME``'s own options by the validation's parser too). A synopsis (``SCENE``,
``[--steps N]``, ``A|B``, ``...``) is a pattern, not a command, and is left out.

README's own ``corpuscle polar wind-tunnel --aoa -10:20:2`` failed: argparse took
``-10:20:2`` for an option name."""
from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest

from corpuscle.cli import build_parser
from corpuscle.cli.validate import options_parser

ROOT = Path(__file__).resolve().parents[2]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]

# a placeholder word (SCENE, RUN.cps, OUT.png, A:B), optional parts, alternatives, an ellipsis
_PLACEHOLDER = re.compile(r"^-*[A-Z][A-Z0-9_]*(\.[a-z0-9]+)?$|^[A-Z]:[A-Z]|[\[\]|<>]|\.\.\.|…")


def _strip_comment(line: str) -> str:
    try:
        words = shlex.split(line, comments=True)
    except ValueError:  # an unclosed quote: not a command as printed
        return ""
    return shlex.join(words)


def documented_commands() -> list[tuple[str, str]]:
    """(where, command) for every concrete ``corpuscle`` command of the docs."""
    found: list[tuple[str, str]] = []
    for path in DOCS:
        text = path.read_text(encoding="utf-8")
        rel = path.relative_to(ROOT)
        in_block = False
        pending = ""
        for n, line in enumerate(text.splitlines(), start=1):
            if line.lstrip().startswith("```"):
                in_block, pending = not in_block, ""
                continue
            if in_block:
                line = pending + line.strip()
                pending = ""
                if line.endswith("\\"):  # a continued command
                    pending = line[:-1] + " "
                    continue
                line = re.sub(r"^\$\s+", "", line)
                if line.startswith("corpuscle "):
                    found.append((f"{rel}:{n}", _strip_comment(line)))
            else:
                # in prose, a span with an option is a command to copy; `corpuscle view` or
                # `corpuscle polar wind-tunnel` alone names a command (its RUN or --aoa left out)
                for span in re.findall(r"`(corpuscle [^`]+)`", line):
                    if any(w.startswith("-") for w in span.split()[1:]):
                        found.append((f"{rel}:{n}", _strip_comment(span)))
    out, seen = [], set()
    for where, cmd in found:
        words = shlex.split(cmd)
        if len(words) < 2 or any(_PLACEHOLDER.search(w) for w in words[1:]) or cmd in seen:
            continue
        seen.add(cmd)
        out.append((where, cmd))
    return out


COMMANDS = documented_commands()


def parse(words: list[str]):
    """The parsed arguments of ``corpuscle WORDS`` (validate's own options included)."""
    args = build_parser().parse_args(words)
    if args.command == "validate":
        _, sub = options_parser(args.name)
        sub.parse_args(args.options)
    return args


def test_the_docs_have_commands():
    # the extraction finds the README's examples (a broken extractor would pass vacuously)
    cmds = {c for _, c in COMMANDS}
    assert "corpuscle polar wind-tunnel --aoa -10:20:2" in cmds
    assert len(cmds) >= 30


@pytest.mark.parametrize("where, command", COMMANDS, ids=[f"{w} {c}" for w, c in COMMANDS])
def test_documented_command_parses_as_printed(where, command, capsys):
    try:
        parse(shlex.split(command)[1:])
    except SystemExit as e:
        pytest.fail(f"{where}: `{command}` is refused by the parser: {capsys.readouterr().err.strip()} "
                    f"(exit {e.code})")
