"""``corpuscle validate all``: every validation, one report, the README's table from it."""

from __future__ import annotations

import json
import sys
import types

import pytest

from cli_script import assert_one_line_error, corpuscle
from corpuscle import validation
from corpuscle.validation import Check, report


def _fake(monkeypatch, name: str, run) -> None:
    """A validation NAME whose run() is `run` (registered for this test only)."""
    mod = types.ModuleType(f"corpuscle.validation._fake_{name}")
    mod.__doc__ = f"``corpuscle validate {name}``: a stand-in for a test.\n\nMore text."
    mod.add_arguments = lambda p: p.add_argument("--plot", default="none")
    mod.run = run
    monkeypatch.setitem(sys.modules, mod.__name__, mod)
    monkeypatch.setitem(validation.VALIDATIONS, name, f"_fake_{name}")


def test_report_of_passing_failing_and_broken_validations(monkeypatch, tmp_path):
    seen = {}

    def good(opts):
        seen["plot"] = opts.plot
        from pathlib import Path

        Path(opts.plot).write_bytes(b"\x89PNG\r\n\x1a\n")  # stands for the plot the validation draws
        return [validation.within("x within 1", 1.5, 1.0, 1.0, "m", "tolerance: the data's scatter")]

    def bad(opts):
        return [validation.within("y within 0.1", 1.5, 1.0, 0.1), validation.within("z", 0.0, 0.0, 0.0)]

    def broken(opts):
        raise ValueError("no such thing\nsecond line")

    _fake(monkeypatch, "good", good)
    _fake(monkeypatch, "bad", bad)
    _fake(monkeypatch, "broken", broken)
    plots = tmp_path / "r_plots"
    plots.mkdir()
    res = report.run_all(["good", "bad", "broken"], None, False, plots)
    assert [r.passed for r in res] == [True, False, False]
    assert seen["plot"] == str(plots / "good.png")  # each validation's plot goes beside the report
    assert res[0].plots == [plots / "good.png"] and res[1].plots == []
    assert res[1].failed == 1
    assert res[2].error.startswith("ValueError: no such thing") and "\n" not in res[2].error
    text = report.markdown(res, {"version": "x"}, "corpuscle validate all", tmp_path)
    assert text.startswith("# Validation report")
    assert "**FAIL** (1 of 3 validations pass)" in text
    assert "| good | A stand-in for a test. | `corpuscle validate good --plot" in text
    assert "PASS: 1 of 1 checks" in text and "FAIL: 1 of 2 checks" in text and "could not run" in text
    assert "| y within 0.1 | 1.5 | 1 | 0.5 | 0.1 | **FAIL** |" in text
    assert "- x within 1: tolerance: the data's scatter" in text
    assert "![good](r_plots/good.png)" in text
    # the README's table is the report's summary
    readme = tmp_path / "README.md"
    readme.write_text(f"# x\n\nbefore\n{report.README_BEGIN}\nold table\n{report.README_END}\nafter\n")
    report.update_readme(readme, res)
    body = readme.read_text()
    assert "old table" not in body and body.startswith("# x\n\nbefore\n") and body.endswith("after\n")
    assert "\n".join(report.summary_rows(res)) in body
    readme.write_text("no markers\n")
    with pytest.raises(ValueError, match="no <!-- validation-table -->"):
        report.update_readme(readme, res)


def test_each_validation_gets_backend_full_and_plot_where_it_takes_them():
    from corpuscle.cli.validate import options_parser

    for name in validation.VALIDATIONS:
        _, parser = options_parser(name)
        argv = report.module_argv(name, parser, "serial", True, None)
        parser.parse_args(argv)  # every option passed is one the validation takes
        have = report._options(parser)
        assert ("--backend" in argv) == ("--backend" in have)
        assert ("--full" in argv) == ("--full" in have)


def test_validate_all_cli(tmp_path):
    out = tmp_path / "rep.md"
    proc = corpuscle("validate", "all", "--only", "hydrostatic", "--backend", "serial", "--report", out,
                     "--json", cwd=tmp_path, timeout=240)
    assert proc.returncode == 0, proc.stderr[-2000:]
    got = json.loads(proc.stdout)
    assert [g["validation"] for g in got] == ["hydrostatic"] and got[0]["passed"]
    text = out.read_text()
    assert "corpuscle validate hydrostatic --backend serial" in text
    for c in got[0]["checks"]:
        assert f"| {c['name']} |" in text
    # a rerun replaces its own report; someone's notes are replaced only with --force
    notes = tmp_path / "notes.md"
    notes.write_text("# my notes\n")
    proc = corpuscle("validate", "all", "--only", "hydrostatic", "--report", notes, cwd=tmp_path)
    assert_one_line_error(proc, "--force")
    assert notes.read_text() == "# my notes\n"


@pytest.mark.parametrize("args, words", [
    (["--only", "nope"], "--only"),
    (["--only", ","], "--only"),
    (["--backend", "gpu"], "--backend"),
    (["--readme", "missing-file.md"], "validation-table"),
    (["--report", "no/such/dir/r.md"], "does not exist"),
])
def test_validate_all_bad_input(tmp_path, args, words):
    assert_one_line_error(corpuscle("validate", "all", *args, cwd=tmp_path, timeout=60), words)
