"""FDIR state machine (table as data): responses, masks, re-baseline, safe mode."""

from __future__ import annotations

import numpy as np

from flight.detector import Detection
from flight.fdir import NOMINAL, RECONFIGURED, REPORTED, SAFE, TRANSITIONS, Fdir
from hil.config import FdirCfg

MANIFOLD_OF = np.array([0, 0, 1, 1])


def _det(i: int, kind: str, group=None) -> Detection:
    g = group or (i,)
    return Detection(tick=5, thruster=i, kind=kind, group=g, names=tuple(map(str, g)), rho=3.0)


def test_stuck_on_closes_the_manifold_and_asks_for_a_rebaseline() -> None:
    f = Fdir(FdirCfg(), MANIFOLD_OF, 2)
    r = f.handle("stuck_on", _det(1, "stuck_on"))
    assert (r.state, r.action, r.rebaseline) == (RECONFIGURED, "close_manifold", True)
    assert f.manifold_open.tolist() == [False, True]
    assert f.available.tolist() == [False, False, True, True]


def test_fail_to_fire_drops_the_thruster_only() -> None:
    f = Fdir(FdirCfg(), MANIFOLD_OF, 2)
    f.handle("fail_to_fire", _det(2, "fail_to_fire"))
    assert f.available.tolist() == [True, True, False, True]
    assert f.manifold_open.tolist() == [True, True]


def test_group_detection_acts_on_the_whole_group() -> None:
    f = Fdir(FdirCfg(), MANIFOLD_OF, 2)
    f.handle("fail_to_fire", _det(0, "fail_to_fire", (0, 2)))
    assert f.available.tolist() == [False, True, False, True]


def test_configured_none_only_reports() -> None:
    f = Fdir(FdirCfg(on_stuck_on="none"), MANIFOLD_OF, 2)
    r = f.handle("stuck_on", _det(1, "stuck_on"))
    assert (r.state, r.rebaseline) == (REPORTED, False)
    assert f.available.all()


def test_nothing_left_is_safe_mode_and_peer_loss_round_trip() -> None:
    f = Fdir(FdirCfg(), MANIFOLD_OF, 2)
    f.handle("stuck_on", _det(0, "stuck_on"))
    f.handle("stuck_on", _det(3, "stuck_on"))
    assert f.state == SAFE and not f.available.any()
    g = Fdir(FdirCfg(), MANIFOLD_OF, 2)
    g.handle("peer_lost")
    assert g.safe_mode and not g.available.any()
    g.handle("peer_back")
    assert g.state == NOMINAL and g.available.all()


def test_table_only_names_known_states() -> None:
    states = {NOMINAL, RECONFIGURED, REPORTED, SAFE}
    for (s, _), (nxt, _) in TRANSITIONS.items():
        assert s in states and nxt in states
