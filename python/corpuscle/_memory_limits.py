"""The memory a process may still allocate, beside the host's free memory.

The core reports the host's ``MemAvailable``; a process under a per-process or container
limit (``ulimit -v``, a cgroup of a container or a batch job) gets less, and a scene sized to
the host's memory then ended minutes later in ``std::bad_alloc``. :func:`process_limit` is
the tightest of the limits the process really has, less what it already uses:

- ``RLIMIT_AS`` (``ulimit -v``) less the process's address space (``VmSize``),
- ``RLIMIT_DATA`` (``ulimit -d``) less its data segment (``VmData``),
- cgroup v2 ``memory.max`` less ``memory.current`` (of its cgroup and every parent),
- cgroup v1 ``memory.limit_in_bytes`` less ``memory.usage_in_bytes``.

The files are read under ``root`` (``/`` but in tests)."""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["process_limit"]

_UNLIMITED = 1 << 60  # cgroup v1 writes 9223372036854771712 for "no limit"


def _read(path: Path) -> str | None:
    try:
        with open(path, encoding="ascii", errors="replace") as f:
            return f.read(4096)
    except OSError:
        return None


def _number(text: str | None) -> int | None:
    if text is None:
        return None
    text = text.strip()
    return int(text) if text.isdigit() else None  # "max" (v2's no limit) and junk: none


def _status_bytes(root: Path, field: str) -> int:
    """``VmSize`` / ``VmData`` of /proc/self/status in bytes (0 where there is none)."""
    for line in (_read(root / "proc/self/status") or "").splitlines():
        if line.startswith(field + ":"):
            parts = line.split()
            if len(parts) >= 2 and parts[1].isdigit():
                return int(parts[1]) * 1024
    return 0


def _rlimits(root: Path) -> list[tuple[float, str]]:
    try:
        import resource
    except ImportError:  # not POSIX
        return []
    out = []
    for name, field, shown in (("RLIMIT_AS", "VmSize", "ulimit -v"), ("RLIMIT_DATA", "VmData", "ulimit -d")):
        which = getattr(resource, name, None)
        if which is None:
            continue
        soft, _ = resource.getrlimit(which)
        if soft != resource.RLIM_INFINITY and soft >= 0:
            out.append((max(0.0, float(soft - _status_bytes(root, field))), f"the process's limit, {shown}"))
    return out


def _cgroup_dirs(root: Path) -> list[tuple[Path, str]]:
    """The memory cgroup folders of this process (v2 and v1), innermost first, with the
    version's name."""
    dirs: list[tuple[Path, str]] = []
    for line in (_read(root / "proc/self/cgroup") or "").splitlines():
        parts = line.split(":", 2)
        if len(parts) != 3:
            continue
        _, controllers, rel = parts
        rel = rel.strip().lstrip("/")
        if controllers == "":  # v2: the one unified hierarchy
            mount, version = root / "sys/fs/cgroup", "v2"
            if not (mount / "cgroup.controllers").exists() and (mount / "unified").is_dir():
                mount = mount / "unified"  # the hybrid layout
        elif "memory" in controllers.split(","):
            mount, version = root / "sys/fs/cgroup/memory", "v1"
        else:
            continue
        here = mount / rel
        if not here.is_dir():  # in a container the cgroup path is the namespace's root
            here = mount
        while True:
            dirs.append((here, version))
            if here == mount or mount not in here.parents:
                break
            here = here.parent
    return dirs


def _cgroups(root: Path) -> list[tuple[float, str]]:
    out = []
    for folder, version in _cgroup_dirs(root):
        if version == "v2":
            limit, used = _number(_read(folder / "memory.max")), _number(_read(folder / "memory.current"))
            shown = "memory.max"
        else:
            limit, used = (_number(_read(folder / "memory.limit_in_bytes")),
                           _number(_read(folder / "memory.usage_in_bytes")))
            shown = "memory.limit_in_bytes"
        if limit is not None and limit < _UNLIMITED:
            out.append((max(0.0, float(limit - (used or 0))), f"the cgroup's limit, {shown}"))
    return out


def process_limit(root: str | os.PathLike = "/") -> tuple[float, str] | None:
    """(bytes the process may still allocate, which limit) for the tightest of its limits,
    or None where it has none."""
    root = Path(root)
    found = _rlimits(root) + _cgroups(root)
    return min(found, key=lambda f: f[0]) if found else None
