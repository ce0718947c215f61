"""Wrong results presented as results: inputs that used to give a number nobody measured, a
state nobody could have reached or a run that went on with what it should have refused.
Each row of a table is one hostile case; each fails before its fix.

The command-line cases go through the installed ``corpuscle`` console script (tests/cli_script.py)."""
import json
import math

import numpy as np
import pytest

pytest.importorskip("corpuscle._core")

import corpuscle
from corpuscle.scene import SceneError, load_scene
from cli_script import assert_one_line_error, corpuscle as run_cli


# --- the wind tunnel's airfoil is checked as placed -----------------------------------------

# (scene, overrides, refused): the angle of attack turns the chord about the leading edge
PLACED_AIRFOILS = [
    # nose down 90 degrees: the trailing edge reaches past the top wall (was accepted)
    ("wind-tunnel", {"airfoil.leading_edge": [-1.2, 0.6], "airfoil.angle_of_attack": -90.0}, True),
    ("wind-tunnel-3d", {"airfoil.leading_edge": [-1.2, 0.6], "airfoil.angle_of_attack": -90.0}, True),
    # nose up 60 degrees near the floor: the trailing edge goes through it (was accepted)
    ("wind-tunnel", {"airfoil.leading_edge": [0.0, -0.7], "airfoil.angle_of_attack": 60.0}, True),
    # a long chord at 80 degrees from the middle: through the floor (was accepted)
    ("wind-tunnel", {"airfoil.chord": 1.5, "airfoil.angle_of_attack": 80.0, "airfoil.leading_edge": [0.0, 0.0]},
     True),
    # upright near the outlet: fits (leading edge + chord > length / 2 was refused)
    ("wind-tunnel", {"airfoil.leading_edge": [1.6, 0.0], "airfoil.angle_of_attack": 90.0}, False),
    ("wind-tunnel-3d", {"airfoil.leading_edge": [1.6, 0.0], "airfoil.angle_of_attack": 90.0}, False),
    # the leading edge itself outside
    ("wind-tunnel", {"airfoil.leading_edge": [-1.9, 0.0]}, True),
]


@pytest.mark.parametrize("scene, overrides, refused", PLACED_AIRFOILS)
def test_wind_tunnel_checks_the_placed_airfoil(scene, overrides, refused):
    base = load_scene(scene)
    if refused:
        with pytest.raises(SceneError, match=r"airfoil\.angle_of_attack = .*not inside the channel") as e:
            base.with_overrides(overrides)
        assert "\n" not in str(e.value)
    else:
        assert base.with_overrides(overrides)["airfoil.angle_of_attack"] == overrides["airfoil.angle_of_attack"]


def test_wind_tunnel_airfoil_past_the_wall_is_one_line_on_the_cli():
    proc = run_cli("run", "wind-tunnel", "--set", "airfoil.leading_edge=[-1.2, 0.6]",
                   "--set", "airfoil.angle_of_attack=-90", "--steps", "1", "--no-progress")
    assert_one_line_error(proc, "not inside the channel")
