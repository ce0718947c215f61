"""`validate dam-break --reference lobovsky|buchner` (validation/impact.py): the measures it
takes of a record (impact time, peak, impulse, level, second peak) on synthetic records with
known answers, the digitised data's own values, and the CI run end to end (one line per
check, a tolerance and a reason beside each)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from corpuscle.validation import impact

from cli_script import assert_one_line_error, corpuscle


def test_measures_of_a_known_record():
    T = np.linspace(0.0, 7.0, 7001)
    P = np.where(T < 2.5, 0.0, 0.6)  # a step to 0.6 at T = 2.5
    P = P + np.where((T >= 2.5) & (T < 2.6), 2.0, 0.0)  # a peak of 2.6 for 0.1
    P = P + np.where((T >= 6.0) & (T < 6.2), 0.3, 0.0)  # a second peak of 0.9
    m = impact.measures(T, P)
    assert m["impact"] == pytest.approx(2.5, abs=1e-3)
    assert m["peak"] == pytest.approx(2.6)
    lo, hi = 2.5 + impact.IMPULSE_WINDOW[0], 2.5 + impact.IMPULSE_WINDOW[1]
    assert m["impulse"] == pytest.approx(0.6 * (hi - 2.5) + 2.0 * 0.1, abs=3e-3)
    assert m["level"] == pytest.approx(0.6) and m["level_sd"] == pytest.approx(0.0, abs=1e-12)
    assert m["second"] == pytest.approx(0.9)


def test_the_data_as_measured():
    d = impact.data("lobovsky2014_sensor1.csv")
    e = impact.measures(d[:, 0], d[:, 1])
    assert e["impact"] == pytest.approx(2.427) and e["peak"] == pytest.approx(2.843)
    assert 0.4 < e["level"] < 0.9 and e["second"] > e["level"]
    b = impact.data("buchner2002_pressure.csv")
    eb = impact.measures(b[:, 0], b[:, 1], impact.IMPACT_LEVELS["buchner"])
    assert 2.4 < eb["impact"] < 2.8  # the same geometry as Lobovsky's: the front arrives alike


def test_ci_run_reports_every_check(tmp_path):
    proc = corpuscle("validate", "dam-break", "--reference", "lobovsky", "--backend", "cpu", "--json", timeout=300)
    assert proc.returncode in (0, 1), proc.stderr
    checks = json.loads(proc.stdout)
    assert len(checks) == 15  # 3 sensors x (impact, peak, impulse, level, second peak)
    for c in checks:
        assert math.isfinite(c["measured"]) and math.isfinite(c["reference"]) and c["tolerance"] > 0
        assert c["detail"] and c["passed"] == (abs(c["measured"] - c["reference"]) <= c["tolerance"])


def test_bad_input():
    assert_one_line_error(corpuscle("validate", "dam-break", "--reference", "nobody"), "--reference")
    assert_one_line_error(corpuscle("validate", "dam-break", "--reference", "lobovsky", "--resolution", "0"),
                          "--resolution")


@pytest.mark.slow
def test_buchner_and_the_sound_study():
    proc = corpuscle("validate", "dam-break", "--reference", "buchner", "--backend", "cpu", "--sound-study",
                     "--json", timeout=1200)
    assert proc.returncode in (0, 1), proc.stderr
    assert len(json.loads(proc.stdout)) == 5
    assert sum(line.strip().startswith("c0 = ") for line in proc.stderr.splitlines()) == 3
