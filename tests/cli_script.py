"""The real ``corpuscle`` console script, as a user runs it, and damaged runs to feed it.

The command-line tests of render, plot and export go through the installed entry point in
a fresh process: the parser, the error and warning printing and the exit code are then the
ones a user meets, not those of a test-only entry point.
"""

from __future__ import annotations

import os
import shutil
import struct
import subprocess
import sys
from pathlib import Path

import pytest


def script() -> str:
    """Path of the installed ``corpuscle`` console script (the one next to this Python first)."""
    beside = Path(sys.executable).with_name("corpuscle")
    if beside.exists():
        return str(beside)
    found = shutil.which("corpuscle")
    if found is None:
        pytest.skip("the corpuscle console script is not installed (pip install .)")
    return found


def corpuscle(*args, cwd=None, timeout: float = 120) -> subprocess.CompletedProcess:
    """Run ``corpuscle ARGS...``; returns the completed process (text stdout and stderr)."""
    env = {k: v for k, v in os.environ.items() if k not in ("CORPUSCLE_DEBUG", "PYTHONWARNINGS")}
    env["COLUMNS"] = "80"
    return subprocess.run([script(), *map(str, args)], cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=timeout)


def assert_one_line_error(proc: subprocess.CompletedProcess, words: str = "") -> None:
    """Bad input: exit code 2, nothing on stdout, one stderr line ``corpuscle: error: ...``."""
    lines = proc.stderr.splitlines()
    assert proc.returncode == 2, proc.stderr
    assert len(lines) == 1 and lines[0].startswith("corpuscle: error: "), proc.stderr
    assert words in lines[0], lines[0]
    assert proc.stdout == "", proc.stdout


def listing(folder: Path) -> set[str]:
    """Every file and folder under ``folder`` (hidden ones included), relative to it."""
    return {str(p.relative_to(folder)) for p in Path(folder).rglob("*")}


def frame_spans(path: Path) -> list[tuple[int, int, int]]:
    """(start, table_len, frame_len) of each whole frame, walked by docs/frame_format.md."""
    raw = Path(path).read_bytes()
    json_len = struct.unpack_from("<Q", raw, 16)[0]
    off, out = -(-(32 + json_len) // 64) * 64, []
    while off + 64 <= len(raw):
        frame_len, = struct.unpack_from("<Q", raw, off + 8)
        table_len, = struct.unpack_from("<I", raw, off + 48)
        if off + frame_len > len(raw):
            break
        out.append((off, table_len, frame_len))
        off += frame_len
    return out


def corrupt_frame(path: Path, k: int) -> None:
    """Flip the last data byte of frame ``k``: it then fails its data checksum on access."""
    start, _, frame_len = frame_spans(path)[k]
    raw = bytearray(Path(path).read_bytes())
    raw[start + frame_len - 1] ^= 0xFF
    Path(path).write_bytes(bytes(raw))


def cut_last_frame(path: Path, keep_bytes: int = 100) -> int:
    """Cut the file inside its last frame (as a crash mid-write does); returns the bytes left of it."""
    start, _, _ = frame_spans(path)[-1]
    raw = Path(path).read_bytes()
    Path(path).write_bytes(raw[:start + keep_bytes])
    return keep_bytes
