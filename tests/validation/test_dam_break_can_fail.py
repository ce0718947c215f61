"""`validate dam-break` at its CI size fails when one thing is wrong, as a reviewer would try
it: the core applying gravity x 0.88 (while the start's hydrostatic column and the time scale
T = t sqrt(2 g / a) use the scene's g), and the Martin & Moyce reference read 0.2 later in T.
The unchanged validation passes (the same run, the same process)."""

from __future__ import annotations

import argparse

import pytest

from corpuscle.kinds import _sph_box
from corpuscle.validation import dam_break as db


def _run():
    p = argparse.ArgumentParser()
    db.add_arguments(p)
    return db.run(p.parse_args(["--backend", "cpu", "--plot", "none"]))


def test_unchanged_passes():
    checks = _run()
    assert all(c.passed for c in checks), [c for c in checks if not c.passed]


def test_gravity_off_by_twelve_percent_fails(monkeypatch):
    build = _sph_box.SphBox.build

    def weak_gravity(self, *a, **k):
        b = build(self, *a, **k)
        b.params["gravity"] = [0.88 * x for x in b.params["gravity"]]
        return b

    monkeypatch.setattr(_sph_box.SphBox, "build", weak_gravity)
    failed = [c.name for c in _run() if not c.passed]
    assert any(name.startswith("balance at release") for name in failed), failed


def test_reference_read_later_fails(monkeypatch):
    reference = db.reference

    def later():
        r = reference().copy()
        r[:, 0] += 0.2
        return r

    monkeypatch.setattr(db, "reference", later)
    failed = [c.name for c in _run() if not c.passed]
    assert any(name.startswith("front") for name in failed), failed
