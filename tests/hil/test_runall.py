"""`hil run-all`'s pure parts: which scenarios, how they are shared among instances."""

from __future__ import annotations

import pytest

from hil.cli import main
from hil.config import SCENARIO_DIR, load_scenario
from hil.errors import UsageError
from hil.runall import _split, scenario_files


def test_every_reference_scenario_is_there_and_valid() -> None:
    names = [p.stem for p in scenario_files(None)]
    for want in ("S000-stuck", "S000-nofire", "S002-100", "S002-50", "S002-15",
                 "S003-progress", "S003-sm", "S003-flex", "S003-flex-rigid",
                 "S004-cart+x", "S004-cart-x", "S004-polar", "REC-stuck", "REC-nofire"):
        assert want in names
    for p in scenario_files(None):
        assert load_scenario(p).cfg.expect is not None, p.stem


def test_split_balances_simulated_time_and_keeps_every_scenario() -> None:
    files = scenario_files(None)
    groups = _split(files, 2)
    assert sorted(p for g in groups for p in g) == sorted(files)
    load = [sum(load_scenario(p).cfg.duration_s for p in g) for g in groups]
    longest = max(load_scenario(p).cfg.duration_s for p in files)
    assert abs(load[0] - load[1]) <= longest
    assert _split(files[:1], 4) == [[files[0]]]


def test_unknown_names_and_bad_jobs_are_usage_errors(capsys) -> None:
    with pytest.raises(UsageError) as err:
        scenario_files(["S000-stuck", "nope"])
    assert "got ['nope']" in str(err.value)
    assert main(["run-all", "--jobs", "0", "--only", "S000-stuck"]) == 2
    assert "--jobs: expected an integer >= 1, got 0" in capsys.readouterr().err
    assert SCENARIO_DIR.exists()
