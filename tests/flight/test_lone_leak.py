"""A stuck-on crossing whose named thruster does not explain the gyro's raw residual, while one
other thruster's leak alone does, names that one (issue 12, ``FlightSoftware._lone_leak``).
orel's adaptive observer takes a stuck middle-belt thruster's roll in as flex: its residual
turned 35-65 deg away from the stuck thruster, outside the neighbours the alike isolation
judges (orel-stuck runs 26 and 88).

Oracles: ``scipy.optimize.nnls`` for each thruster's leak fit (one size, not negative) and
the share of the raw residual it explains; the plant's truth in the closed-loop run.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import nnls

import flight.software
from flight.detector import STUCK_ON, Detection
from flight.software import _LONE_EXPLAINED, _LONE_NAMED, FlightSoftware
from hil.config import AttitudeCfg, load_vehicle
from tests.flight.campaign_run import campaign_run

H = 0.2


def _flight() -> FlightSoftware:
    return FlightSoftware(load_vehicle("orel"),
                          initial_attitude=AttitudeCfg(axis=(1, 0, 0), angle_deg=0.0))


def _window(fs: FlightSoftware, raw_of, ticks: int, rng) -> None:
    """``ticks`` evidence ticks of random burns (none of the thrusters judged here), the raw
    residual ``raw_of(k, eff)`` plus gyro-size noise; the observer's residual is not read."""
    for k in range(ticks):
        eff = np.where(rng.random(fs.n) < 0.15, rng.uniform(0.02, H, fs.n), 0.0)
        eff[[fs.arrays.names.index(n) for n in ("6", "8", "18", "27", "29")]] = 0.0
        raw = raw_of(k, eff) + 5e-6 * rng.standard_normal(3)
        fs._window.append((np.zeros(3), eff, True, raw, 0))


def _crossing(fs: FlightSoftware, j: int) -> Detection:
    return Detection(tick=0, thruster=j, kind=STUCK_ON, group=fs.detector.groups[j],
                     names=tuple(fs.arrays.names[g] for g in fs.detector.groups[j]), rho=1.0,
                     source="residual")


def _explained(fs: FlightSoftware, j: int) -> float:
    raw = np.array([w[3] for w in fs._window]).reshape(-1)
    closed = H - np.array([w[1] for w in fs._window])
    x = (closed[:, j, None] * fs.arrays.mu_B_rad_s2[j][None, :]).reshape(-1, 1)
    _, r = nnls(x, raw)
    return 1.0 - r ** 2 / float(raw @ raw)


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("stuck, named", [("27", "8"), ("29", "6")])
def test_the_one_leak_that_explains_the_raw_residual_is_named(seed, stuck, named) -> None:
    """The raw residual is ``stuck``'s full leak; the crossing named ``named`` (48 and 65 deg
    away, as in orel-stuck runs 26 and 88): ``stuck`` is named."""
    rng = np.random.default_rng(seed)
    fs = _flight()
    s, n = fs.arrays.names.index(stuck), fs.arrays.names.index(named)
    mu = fs.arrays.mu_B_rad_s2
    _window(fs, lambda k, eff: mu[s] * (H - eff[s]), 4 + seed, rng)
    assert _explained(fs, s) >= _LONE_EXPLAINED and _explained(fs, n) < _LONE_NAMED
    det = fs._isolate_alike(_crossing(fs, n), np.ones(fs.n, bool), np.zeros(3))
    assert det.thruster == s and det.source == "isolation"


@pytest.mark.parametrize("seed", range(4))
def test_a_named_thruster_that_explains_half_is_kept(seed) -> None:
    """The raw residual is the named thruster's 60 % leak plus a roll ringing of half its size
    (orel's roll modes): the named one explains at least half of it and stays named."""
    rng = np.random.default_rng(seed)
    fs = _flight()
    n = fs.arrays.names.index("27")
    mu = fs.arrays.mu_B_rad_s2
    amp = 0.3 * float(np.linalg.norm(mu[n])) * H
    _window(fs, lambda k, eff: 0.6 * mu[n] * (H - eff[n])
            + amp * np.array([np.cos(2 * np.pi * 0.3 * H * k + seed), 0.0, 0.0]), 5, rng)
    assert _explained(fs, n) >= _LONE_NAMED
    det = fs._isolate_alike(_crossing(fs, n), np.ones(fs.n, bool), np.zeros(3))
    assert det.thruster == n and det.source == "residual"


def _size(fs: FlightSoftware, j: int) -> float:
    raw = np.array([w[3] for w in fs._window]).reshape(-1)
    closed = H - np.array([w[1] for w in fs._window])
    x = (closed[:, j, None] * fs.arrays.mu_B_rad_s2[j][None, :]).reshape(-1, 1)
    return float(nnls(x, raw)[0][0])


@pytest.mark.parametrize("leaking", ["29", "18"])
def test_a_neighbour_is_named_only_at_a_plausible_size(leaking) -> None:
    """18 (front belt, roll lever arm) and 29 (middle belt) are 15.5 deg apart; 18's
    acceleration is ten times 29's. Both have stuck-on evidence, the crossing names 29. A 50 %
    leak of 29 turned 70 % of the way toward 18's direction (as orel's flex turned it in
    orel-faults run 84, named 18 there): 18 fits it at under a tenth of its thrust and 29 stays
    named, though 18 is the better aligned. A 50 % leak of 18: both fit at a plausible size
    (29 at about five times its thrust: no upper bound among neighbours) and the direction
    names 18."""
    rng = np.random.default_rng(1)
    fs = _flight()
    names = fs.arrays.names
    a, b = names.index("29"), names.index("18")
    j, other = (a, b) if leaking == "29" else (b, a)
    e = fs.detector.e_B
    turned = 0.3 * e[j] + 0.7 * e[other] if leaking == "29" else e[j]
    turned = turned / np.linalg.norm(turned)
    mag = 0.5 * float(np.linalg.norm(fs.arrays.mu_B_rad_s2[j]))
    _window(fs, lambda k, eff: mag * (H - eff[j]) * turned, 5, rng)
    fs.detector.rho_off[[a, b]] = fs.detector.thresholds_off[[a, b]]
    total = np.sum([w[3] for w in fs._window], axis=0)
    assert total @ e[b] > total @ e[a]  # by direction alone: 18
    det = fs._isolate_alike(_crossing(fs, a), np.ones(fs.n, bool), np.zeros(3))
    if leaking == "29":
        assert _size(fs, b) < flight.software._LONE_SIZE[0] <= _size(fs, a)
        assert det.thruster == a
    else:
        assert min(_size(fs, a), _size(fs, b)) >= flight.software._LONE_SIZE[0]
        assert det.thruster == b


def test_too_few_ticks_leave_the_crossing_alone() -> None:
    """Under the alike isolation's minimum of evidence ticks nothing is judged again."""
    rng = np.random.default_rng(0)
    fs = _flight()
    s, n = fs.arrays.names.index("29"), fs.arrays.names.index("6")
    _window(fs, lambda k, eff: fs.arrays.mu_B_rad_s2[s] * (H - eff[s]),
            flight.software._ALIKE_MIN_TICKS - 1, rng)
    det = fs._isolate_alike(_crossing(fs, n), np.ones(fs.n, bool), np.zeros(3))
    assert det.thruster == n


def test_a_stuck_thruster_the_observer_turned_away_from_is_named(tmp_path, monkeypatch) -> None:
    """orel-stuck run 88: 29 stuck on at 27.95 s, in a hold after a slew. The observer's
    residual crossed along 6 (65 deg away); the raw residual is 29's leak. 29 is named first,
    at the crossing; without the lone-leak judgement 6 was named first (the oracle: the test
    can fail)."""
    spec, r = campaign_run(tmp_path, "orel-stuck", 88)
    assert spec.fault == {"kind": "stuck_on", "t_s": pytest.approx(27.95, abs=0.01),
                          "thruster": "29", "fraction": 1.0}
    dets = r.summary["detections"]
    assert (dets[0]["thruster"], dets[0]["type"]) == ("29", "stuck_on"), dets
    assert dets[0]["latency_s"] < 1.5, dets
    monkeypatch.setattr(flight.software, "_LONE_EXPLAINED", 1.01)
    _, r0 = campaign_run(tmp_path / "off", "orel-stuck", 88)
    assert r0.summary["detections"][0]["thruster"] == "6", r0.summary["detections"]
