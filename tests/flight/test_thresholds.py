"""Thresholds tool (docs/design.md 6.4 step 6) and `hil thresholds`."""

from __future__ import annotations

import json

import numpy as np
import pytest

from flight.errors import ThresholdError
from flight.thresholds import progression, propose, ticks_to_reach
from hil.cli import main


def test_progression_closed_form() -> None:
    w = 0.8
    rho = 0.0
    for n in range(30):
        rho = w * rho + 0.5
        assert progression(0.5, w, n) == pytest.approx(rho)


def test_ticks_to_reach_matches_the_recursion() -> None:
    for w, thr in [(0.8, 2.5), (0.9, 5.0), (0.95, 3.0)]:
        n = ticks_to_reach(thr, 1.0, w)
        assert progression(1.0, w, n - 1) > thr >= progression(1.0, w, n - 2)
    assert ticks_to_reach(5.0, 1.0, 0.8) is None  # at the limit 1 / (1 - w)


def test_proposal_meets_time_and_margin() -> None:
    p = propose(2.0, 0.2, xi_mean=0.02, xi_max=1.0, run=2, margin=1.5)
    assert p.detection_time_s <= 2.0
    assert p.threshold >= 1.5 * p.no_fault_max
    assert p.threshold < p.limit


def test_sequences_from_a_file(tmp_path, capsys) -> None:
    rng = np.random.default_rng(0)
    xi = np.where(rng.random((500, 4)) < 0.01, rng.uniform(-1, 1, (500, 4)), 0.0)
    f = tmp_path / "nofault.json"
    f.write_text(json.dumps({"xi": xi.tolist()}))
    assert main(["thresholds", "--detection-time", "3", "--stats", str(f)]) == 0
    assert "proposal: forgetting_on" in capsys.readouterr().out


def test_errors_are_one_line(tmp_path, capsys) -> None:
    assert main(["thresholds", "--detection-time", "-1"]) == 2
    assert capsys.readouterr().err == (
        "error: hil thresholds: argument --detection-time: expected a finite number > 0 and "
        "<= 86400, got '-1' (see hil thresholds --help)\n")
    assert main(["thresholds", "--detection-time", "1", "--stats", str(tmp_path / "x.json")]) == 2
    assert "no such file" in capsys.readouterr().err
    with pytest.raises(ThresholdError):
        propose(0.2, 0.2, xi_max=1.0, run=5, margin=10.0)
