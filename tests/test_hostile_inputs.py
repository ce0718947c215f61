

def test_a_container_too_large_for_the_grid_names_the_keys(tmp_path):
    # was "the grid needs more than 1024 cells per axis (h too small for the container)"
    p = run_cli("run", "magic8ball", "--backend", "serial", "--particles", "300", "--steps", "1",
                "--set", "container.radius=100", "--out", tmp_path / "m.cps")
    assert_one_line_error(p, "container.radius = 100 m spans more than 1024 cells per axis of the neighbour radius "
                             "h (1 + sph.skin) = ")
    assert "lower container.radius or raise sph.h" in p.stderr
