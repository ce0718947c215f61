"""The tables and the plot of a benchmark sweep (``corpuscle bench`` over sizes, backends and
neighbour indexes; ``benchmarks/fluid_box_sweep.py``): steps/s for every configuration and size,
seed 002's speedup tables (every configuration over serial and over OpenMP, on one index), and a
log-log plot of particle-steps/s against particles. Rows are ``corpuscle bench --json`` rows."""

from __future__ import annotations

from typing import Any, Sequence

Row = dict[str, Any]

# the backends' names in the tables
_NAMES = {"serial": "serial", "cpu": "OpenMP", "cuda": "CUDA"}


def _config(row: Row) -> tuple[str, str]:
    """A row's (backend, index)."""
    return row["backend"], str(row.get("neighbors"))


def configurations(rows: Sequence[Row]) -> list[tuple[str, str]]:
    """(backend, index) pairs in the order they first appear."""
    return list(dict.fromkeys(_config(r) for r in rows))


def _label(config: tuple[str, str]) -> str:
    b, i = config
    return f"{_NAMES.get(b, b)} {i}"


def _sizes(rows: Sequence[Row]) -> list[int]:
    return sorted({int(r["particles"]) for r in rows})


def _get(rows: Sequence[Row], config: tuple[str, str], n: int) -> Row | None:
    return next((r for r in rows if _config(r) == config and r["particles"] == n), None)


def _reference_index(rows: Sequence[Row]) -> str:
    """The index the speedup tables divide by: grid where it was timed (the seed's), else the
    first one."""
    idx = [i for _, i in configurations(rows)]
    return "grid" if "grid" in idx else idx[0]


def steps_table(rows: Sequence[Row]) -> list[str]:
    """Markdown: steps/s of every configuration (columns) at every size (rows), with the mean
    neighbour count."""
    cols = configurations(rows)
    lines = ["| particles | neighbours | " + " | ".join(_label(c) for c in cols) + " |",
             "|---:|---:|" + "---:|" * len(cols)]
    for n in _sizes(rows):
        nb = next((r["mean_neighbors"] for r in rows if r["particles"] == n and r.get("mean_neighbors")), None)
        cells = [f"{r['steps_per_second']:.4g}" if (r := _get(rows, c, n)) else "" for c in cols]
        lines.append(f"| {n:,} | " + (f"{nb:.0f}" if nb is not None else "") + " | " + " | ".join(cells) + " |")
    return lines


def speedup_tables(rows: Sequence[Row]) -> list[str]:
    """Markdown: seed 002's tables, every configuration's steps/s over serial's and over OpenMP's
    on the reference index at the same size; empty when the rows have a single configuration or
    neither reference."""
    cols = configurations(rows)
    if len(cols) < 2:
        return []
    ref = _reference_index(rows)
    lines: list[str] = []
    for backend in ("serial", "cpu"):
        base_config = (backend, ref)
        if base_config not in cols:
            continue
        body = []
        for n in _sizes(rows):
            base = _get(rows, base_config, n)
            if not base or not base["steps_per_second"] > 0:
                continue
            cells = [f"{r['steps_per_second'] / base['steps_per_second']:.3g}x" if (r := _get(rows, c, n)) else ""
                     for c in cols]
            body.append(f"| {n:,} | " + " | ".join(cells) + " |")
        if body:
            if lines:
                lines.append("")
            lines += [f"speedup over {_label(base_config)}:", "",
                      "| particles | " + " | ".join(_label(c) for c in cols) + " |", "|---:|" + "---:|" * len(cols)]
            lines += body
    return lines


def plot(rows: Sequence[Row], path, title: str = "") -> None:
    """particle-steps/s against particles, a line for every configuration (log-log PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5))
    try:
        for c in configurations(rows):
            rs = sorted((r for r in rows if _config(r) == c), key=lambda r: r["particles"])
            ax.loglog([r["particles"] for r in rs], [r["particle_steps_per_second"] for r in rs], "-o", ms=3,
                      label=_label(c))
        ax.set_xlabel("particles")
        ax.set_ylabel("particle-steps per second")
        if title:
            ax.set_title(title)
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=8)
        fig.tight_layout()
        fig.savefig(path, dpi=120)
    finally:
        plt.close(fig)
