"""corpuscle.airfoils: the Selig / Lednicer .dat reader, NACA 4-digit sections against their
closed-form thickness and camber, flat plates, place(), validation, the shipped data."""

import math
from importlib import resources

import numpy as np
import pytest

from corpuscle import airfoils

# a small section written both ways: TE (1, 0), upper (0.5, 0.1), LE (0, 0), lower (0.5, -0.05)
SELIG = "TEST SECTION\r\n# a comment\r\n 1.0 0.0\r\n\r\n 0.5 0.1\r\n 0.0 0.0\r\n 0.5 -0.05\r\n 1.0 0.0\r\n"
LEDNICER = "TEST SECTION\n   3.   3.\n\n 0.0 0.0\n 0.5 0.1\n 1.0 0.0\n\n 0.0 0.0  # leading edge\n 0.5 -0.05\n 1.0 0.0\n"
EXPECTED = np.array([[1.0, 0.0], [0.5, 0.1], [0.0, 0.0], [0.5, -0.05]])


def write(tmp_path, text, name="section.dat"):
    p = tmp_path / name
    p.write_bytes(text.encode())
    return p


def yt_reference(x, t, a4):
    # Abbott & von Doenhoff (1959) eq. 6.2, written out independently of the module
    return 5 * t * (0.2969 * np.sqrt(x) - 0.1260 * x - 0.3516 * x**2 + 0.2843 * x**3 + a4 * x**4)


def test_selig_file_with_crlf_blank_lines_and_comments(tmp_path):
    p = airfoils.read_dat(write(tmp_path, SELIG))
    assert p.dtype == np.float64 and p.shape == (4, 2)
    np.testing.assert_allclose(p, EXPECTED, atol=1e-15)
    assert airfoils.signed_area(p) > 0


def test_lednicer_file_gives_the_same_polygon_as_selig(tmp_path):
    np.testing.assert_allclose(airfoils.read_dat(write(tmp_path, LEDNICER)), EXPECTED, atol=1e-15)


def test_clockwise_file_is_reversed_to_counter_clockwise(tmp_path):
    cw = "CW\n1 0\n0.5 -0.05\n0 0\n0.5 0.1\n1 0\n"
    p = airfoils.read_dat(write(tmp_path, cw))
    assert airfoils.signed_area(p) > 0
    assert {tuple(v) for v in p} == {tuple(v) for v in EXPECTED}


def test_normalisation_moves_le_to_origin_and_scales_the_chord(tmp_path):
    # the section scaled by 2, shifted and rotated by 5 degrees
    a = math.radians(5)
    rot = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    pts = np.vstack([EXPECTED, EXPECTED[:1]]) * 2 @ rot.T + (3.0, -1.0)
    text = "moved\n" + "".join(f"{x:.17g} {y:.17g}\n" for x, y in pts)
    np.testing.assert_allclose(airfoils.read_dat(write(tmp_path, text)), EXPECTED, atol=1e-12)
    raw = airfoils.read_dat(write(tmp_path, text), normalize_chord=False)
    np.testing.assert_allclose(raw, pts[:-1], atol=1e-12)


def test_e398_shipped_closed_ccw_unit_chord_le_at_origin():
    p = airfoils.load("e398")
    assert p.shape == (71, 2)  # 36 upper + 37 lower, the shared LE and the closing TE once
    airfoils.validate_polygon(p)
    assert airfoils.signed_area(p) > 0
    assert not np.array_equal(p[0], p[-1])
    assert (np.all(p == 0.0, axis=1)).sum() == 1  # the leading edge vertex at the origin
    np.testing.assert_allclose(p[0], (1.0, 0.0), atol=1e-12)  # the trailing edge
    assert p[:, 0].min() >= -1e-9 and p[:, 0].max() <= 1 + 1e-12
    # Eppler 398 as in the file: the upper surface reaches y = 0.12, the lower y = -0.033
    assert 0.11 < p[:, 1].max() < 0.13 and -0.04 < p[:, 1].min() < -0.03


def test_shipped_data_files_are_package_resources():
    d = resources.files("corpuscle") / "data"
    assert (d / "e398.dat").is_file()
    assert (d / "dam_break_martin_moyce.csv").is_file()
    assert "e398" in airfoils.shipped()


def test_load_by_name_and_path(tmp_path):
    np.testing.assert_array_equal(airfoils.load("NACA2412"), airfoils.naca4("2412"))
    np.testing.assert_allclose(airfoils.load(write(tmp_path, SELIG)), EXPECTED)
    with pytest.raises(ValueError, match="unknown airfoil"):
        airfoils.load("no-such-section")


@pytest.mark.parametrize("closed_te, a4", [(False, -0.1015), (True, -0.1036)])
def test_naca0012_thickness_matches_the_closed_form(closed_te, a4):
    n = 100
    p = airfoils.naca4("0012", n=n, closed_te=closed_te)
    upper = p[: n + 1][::-1]  # LE -> TE
    x = upper[:, 0]
    np.testing.assert_allclose(x, 0.5 * (1 - np.cos(np.linspace(0, math.pi, n + 1))), atol=1e-15)  # cosine spacing
    ref = yt_reference(x, 0.12, a4)
    if closed_te:
        ref[-1] = 0.0
    np.testing.assert_allclose(upper[:, 1], ref, atol=1e-15)
    # a few stations by value (NACA Report 824 tabulates y_t(0.3) = 0.06002 for the 0012)
    np.testing.assert_allclose(airfoils.naca4_thickness([0.3], "0012"), [0.06002], atol=2e-5)
    lower = p[n:]
    np.testing.assert_allclose(lower[1:, 1], -yt_reference(lower[1:, 0], 0.12, a4), atol=1e-15)
    if closed_te:
        assert len(p) == 2 * n and np.array_equal(p[0], (1.0, 0.0))
    else:
        assert len(p) == 2 * n + 1
        np.testing.assert_allclose(p[0, 1] - p[-1, 1], 2 * yt_reference(1.0, 0.12, -0.1015), rtol=1e-12)
        assert abs(p[0, 1] - p[-1, 1] - 0.00252) < 1e-5


@pytest.mark.parametrize("code, t", [("0012", 0.12), ("0006", 0.06), ("2412", 0.12), ("4421", 0.21)])
def test_naca_max_thickness_is_the_last_two_digits(code, t):
    n = 400
    p = airfoils.naca4(code, n=n, closed_te=False)
    up, lo = p[: n + 1][::-1], p[n:]
    thick = np.hypot(*(up[1:] - lo[1:]).T)  # upper and lower of one station straddle the mean line
    assert abs(thick.max() - t) < 2e-4 * t / 0.12
    x = 0.5 * (1 - np.cos(np.linspace(0, math.pi, n + 1)))[1:]
    assert abs(x[np.argmax(thick)] - 0.30) < 0.01  # the maximum near 30 % chord


@pytest.mark.parametrize("code, m, pos", [("2412", 0.02, 0.4), ("4415", 0.04, 0.4), ("6309", 0.06, 0.3)])
def test_naca_camber_line_maximum_at_the_right_position(code, m, pos):
    n = 200
    p = airfoils.naca4(code, n=n, closed_te=True)
    up = p[: n + 1][::-1]  # stations 0..n
    lo = p[n : 2 * n]  # stations 0..n-1
    mid = 0.5 * (up[1:n] + lo[1:n])
    assert abs(mid[:, 1].max() - m) < 1e-5
    assert abs(mid[np.argmax(mid[:, 1]), 0] - pos) < 0.01
    yc, _ = airfoils.naca4_camber(mid[:, 0], code)
    np.testing.assert_allclose(mid[:, 1], yc, atol=1e-12)  # the midpoints lie on the mean line
    assert np.array_equal(p[n], (0.0, 0.0))


def test_naca_rejects_bad_codes():
    for code in ("241", "20x2", "2012", "0412", "0000"):
        with pytest.raises(ValueError, match="naca4"):
            airfoils.naca4(code)


def test_flat_plate_rectangle_and_rounded():
    r = airfoils.flat_plate(0.02)
    assert r.shape == (4, 2) and abs(airfoils.signed_area(r) - 0.02) < 1e-15
    t = 0.05
    q = airfoils.flat_plate(t, rounded=True, n_arc=64)
    airfoils.validate_polygon(q)
    exact = t * (1 - t) + math.pi * (t / 2) ** 2
    assert abs(airfoils.signed_area(q) - exact) < 1e-3 * exact
    assert np.array_equal(q[33], (0.0, 0.0))
    np.testing.assert_allclose(q[:, 0].min(), 0.0, atol=1e-15)
    np.testing.assert_allclose(q[:, 0].max(), 1.0, atol=1e-15)


def test_place_rotates_nose_up_about_the_leading_edge():
    p = airfoils.naca4("0012")
    w = airfoils.place(p, chord=0.5, angle_of_attack_deg=10, leading_edge=(-1.2, 0.3))
    a = math.radians(10)
    np.testing.assert_allclose(w[len(p) // 2], (-1.2, 0.3), atol=1e-15)  # the LE stays put
    np.testing.assert_allclose(w[0], (-1.2 + 0.5 * math.cos(a), 0.3 - 0.5 * math.sin(a)), atol=1e-12)
    assert w[0, 1] < 0.3  # the trailing edge goes down for a positive angle
    assert airfoils.signed_area(w) == pytest.approx(0.25 * airfoils.signed_area(p), rel=1e-12)
    neg = airfoils.place(p, 0.5, -10, (-1.2, 0.3))
    assert neg[0, 1] > 0.3
    np.testing.assert_allclose(airfoils.place(p, 1.0, 0.0), p, atol=1e-15)


@pytest.mark.parametrize(
    "poly, match",
    [
        ([[0, 0], [0, 1], [1, 1], [1, 0]], "clockwise"),
        ([[0, 0], [1, 1], [1, 0], [0, 1]], "intersects itself"),
        ([[0, 0], [1, 0], [1, 1], [0, 0]], "repeats the first"),
        ([[0, 0], [1, 0], [1, 0], [1, 1]], "coincide"),
        ([[0, 0], [1, 0], [np.nan, 1]], "not finite"),
        ([[0, 0], [1, 0]], "at least 3"),
        ([[0, 0], [2, 0], [2, 1], [1, -1], [0, 1]], "intersects itself"),
    ],
)
def test_validate_polygon_errors(poly, match):
    with pytest.raises(ValueError, match=match) as e:
        airfoils.validate_polygon(np.array(poly, dtype=float), "wing")
    assert str(e.value).startswith("wing:") and "\n" not in str(e.value)


@pytest.mark.parametrize(
    "text, line, match",
    [
        ("T\n1 0\n0.5 0.1\n0 zero\n0.5 -0.1\n", 4, "expected two numbers"),
        ("T\n1 0\n0.5 0.1 0.3\n0 0\n", 3, "expected two numbers"),
        ("T\n1 0\n0.5 nan\n0 0\n0.5 -0.1\n", 3, "non-finite"),
        ("T\n1 0\n0.5 inf\n0 0\n0.5 -0.1\n", 3, "non-finite"),
        ("T\n1 0\n\n0.5 0.1\n0.5 0.1\n0 0\n0.5 -0.1\n", 5, "duplicate point"),
        ("T\n1 0\n0 0\n", 3, "too few points"),
        ("T\n1 0\n", 1, "no coordinates|too few"),
        ("T\n 3. 3.\n0 0\n0.5 0.1\n1 0\n0 0\n0.5 -0.1\n", 2, "announces 3 upper and 3 lower"),
    ],
)
def test_bad_files_give_one_line_errors_naming_file_and_line(tmp_path, text, line, match):
    path = write(tmp_path, text, "bad.dat")
    with pytest.raises(ValueError, match=match) as e:
        airfoils.read_dat(path)
    msg = str(e.value)
    assert "\n" not in msg
    assert msg.startswith(f"{path}:{line}:") or (line == 1 and msg.startswith(f"{path}:")), msg


def test_missing_file_is_a_value_error(tmp_path):
    with pytest.raises(ValueError, match="cannot read"):
        airfoils.read_dat(tmp_path / "absent.dat")
