"""corpuscle plot: the recorded time series, labelled, and bad input."""

from __future__ import annotations

import numpy as np
import pytest

from corpuscle.plot import PlotError, plot_run

import viz_runs

pytest.importorskip("matplotlib")


def lines_by_label(fig) -> dict:
    """Every plotted line of a figure by its label, with the axes it is on."""
    return {ln.get_label(): (ax, ln) for ax in fig.axes for ln in ax.get_lines()}


def test_magic8ball_series_are_plotted_with_units(tmp_path):
    viz_runs.write_magic8ball(tmp_path / "m8.cps", frames=5)
    out = tmp_path / "m8.png"
    fig = plot_run(tmp_path / "m8.cps", out)
    lines = lines_by_label(fig)
    assert set(lines) == {"dt", "kinetic_energy", "density_error", "mean_density", "die_height", "die_speed",
                          "n_particles", "n_ghosts"}
    # each line carries the recorded values against time
    ax, ln = lines["kinetic_energy"]
    np.testing.assert_allclose(ln.get_xdata(), 0.02 * np.arange(5))
    np.testing.assert_allclose(ln.get_ydata(), 0.01 * (np.arange(5) + 1))
    assert ax.get_ylabel() == "kinetic energy [J]" and ax.get_xlabel() == "time [s]"
    assert lines["dt"][0].get_ylabel() == "dt [s]" and lines["dt"][0].get_yscale() == "log"
    assert lines["die_height"][0].get_ylabel() == "die height [m]"
    assert lines["die_speed"][0].get_ylabel() == "die speed [m/s]"
    assert lines["n_particles"][0] is lines["n_ghosts"][0]
    # the file is a PNG of the figure's size
    from PIL import Image

    with Image.open(out) as im:
        assert im.format == "PNG" and im.size == tuple(int(v) for v in fig.get_size_inches() * fig.dpi)


def test_wind_tunnel_forces_and_coefficients_share_panels(tmp_path):
    viz_runs.write_tunnel(tmp_path / "wt.cps", frames=4)
    fig = plot_run(tmp_path / "wt.cps", tmp_path / "wt.svg")
    lines = lines_by_label(fig)
    assert {"lift", "drag", "cl", "cd", "n_particles", "dt"} <= set(lines)
    assert lines["lift"][0] is lines["drag"][0] and lines["cl"][0] is lines["cd"][0]
    assert lines["lift"][0].get_ylabel() == "lift and drag [N/m]"
    np.testing.assert_allclose(lines["drag"][1].get_ydata(), 0.5 + 0.1 * np.arange(4))
    assert (tmp_path / "wt.svg").read_text().lstrip().startswith("<?xml")


def test_series_can_be_chosen(tmp_path):
    viz_runs.write_magic8ball(tmp_path / "m8.cps", frames=3)
    fig = plot_run(tmp_path / "m8.cps", series="die_height,die_speed")
    assert set(lines_by_label(fig)) == {"die_height", "die_speed"}
    with pytest.raises(PlotError, match="unknown series 'lift'"):
        plot_run(tmp_path / "m8.cps", series=["lift"])


# the command line (and its bad input) is tested through the console script: test_viz_console.py


def test_missing_matplotlib_names_the_pip_install(tmp_path, monkeypatch):
    import sys

    viz_runs.write_magic8ball(tmp_path / "m8.cps", frames=2)
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    with pytest.raises(PlotError, match="pip install matplotlib"):
        plot_run(tmp_path / "m8.cps")


def test_a_failed_save_leaves_no_partial_file_and_keeps_the_old_one(tmp_path, monkeypatch):
    from matplotlib.figure import Figure

    from cli_script import listing

    viz_runs.write_magic8ball(tmp_path / "m8.cps", frames=2)
    plot_run(tmp_path / "m8.cps", tmp_path / "p.png")
    old = (tmp_path / "p.png").read_bytes()

    def half_written(self, fname, *args, **kwargs):
        with open(fname, "wb") as f:
            f.write(b"\x89PNG\r\n\x1a\n half")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(Figure, "savefig", half_written)
    with pytest.raises(PlotError, match="No space left on device"):
        plot_run(tmp_path / "m8.cps", tmp_path / "p.png")
    with pytest.raises(PlotError, match="No space left on device"):
        plot_run(tmp_path / "m8.cps", tmp_path / "q.svg")
    assert listing(tmp_path) == {"m8.cps", "p.png"} and (tmp_path / "p.png").read_bytes() == old
