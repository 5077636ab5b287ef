"""Stuck-on isolation among thrusters of near directions (issue 12).

orel's aft belt has neighbours 15-30 deg apart in acceleration direction. Its adaptive
observer takes part of a stuck thrust in as flex, which turns the observer's residual toward
a neighbour; the gyro's raw residual still points at the stuck thruster
(``FlightSoftware._isolate_alike``). Oracle: the fault the shipped campaign injects (runs
whose first detection named a neighbour before this isolation).
"""

from __future__ import annotations

from pathlib import Path

import pytest

from hil.campaign.expansion import expand_run, write_run
from hil.campaign.load import load_campaign
from hil.config import CONFIG_DIR
from hil.sim import simulate


@pytest.mark.parametrize("run", [0, 33, 126])
def test_orel_stuck_on_is_named_among_near_neighbours(tmp_path: Path, run: int) -> None:
    c = load_campaign(CONFIG_DIR / "campaigns" / "orel-faults.yaml")
    spec = expand_run(c, run)
    assert spec.fault["kind"] == "stuck_on"
    r = simulate(write_run(spec, tmp_path))
    after = [d for d in r.summary["detections"] if d["t_s"] >= spec.fault["t_s"]]
    assert after, "missed"
    first = after[0]
    assert first["type"] == "stuck_on" and first["correct"], (spec.fault, first)
    assert first["t_s"] - spec.fault["t_s"] <= 2.0
