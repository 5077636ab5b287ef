"""The shipped campaign files (``configs/campaigns``) load as ``hil campaign`` loads them (their
first runs through the scenario loader), and the fails-to-fire campaigns give what their
header says: only those two kinds, every thruster of the vehicle with both, five rounds.

Oracle: the vehicle files' own thruster lists (``load_vehicle``), not the campaign's."""

from __future__ import annotations

from collections import Counter

import pytest

from hil.campaign.expansion import expand_run
from hil.campaign.load import load_campaign
from hil.config import CONFIG_DIR, load_vehicle

CAMPAIGNS = sorted((CONFIG_DIR / "campaigns").glob("*.yaml"))


@pytest.mark.parametrize("path", CAMPAIGNS, ids=[p.stem for p in CAMPAIGNS])
def test_every_shipped_campaign_loads(path) -> None:
    c = load_campaign(path)
    assert c.runs > 0


@pytest.mark.parametrize("vehicle", ["iss_rs", "orel"])
def test_the_fails_campaigns_give_every_thruster_both_kinds_five_times(vehicle: str) -> None:
    c = load_campaign(CONFIG_DIR / "campaigns" / f"{vehicle}-fails.yaml")
    names = [t.name for t in load_vehicle(vehicle).thrusters]
    seen = Counter()
    for k in range(c.runs):
        f = expand_run(c, k).fault
        assert f["kind"] in ("fail_to_fire", "degraded")
        assert 2.0 <= f["t_s"] <= 40.0
        if f["kind"] == "degraded":
            assert 0.2 <= f["fraction"] <= 0.6
        seen[(f["thruster"], f["kind"])] += 1
    assert set(seen) == {(n, k) for n in names for k in ("fail_to_fire", "degraded")}
    assert set(seen.values()) == {5}
