"""The burn-fraction test (issue 12): a thruster whose burns, many of them, fall short of what
it should give is degraded, even when each burn's deficit sits inside the per-tick dead zone.

Oracles: the thrust the synthetic burns are built from; ``scipy.optimize.nnls`` for the
one-parameter fit with a sign; the direction of a leak against that of a deficit (a thruster
stuck on pushes along its own acceleration direction, a weak one short of its own); the fault
the plant is given (closed loop, the flight core and the plant core as in
tests/flight/test_fdir_envelope.py).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import nnls

from common.errors import ConfigError
from flight.detector import DEGRADED, Effectiveness
from flight.software import FlightSoftware, _rss_one
from hil.config import AttitudeCfg, FaultSpec, InitialCfg, load_vehicle
from tests.flight.test_fdir_envelope import MU, _run

H = 0.2


@pytest.mark.parametrize("seed", range(5))
def test_rss_of_the_signed_one_parameter_fit_is_nnls(seed: int) -> None:
    rng = np.random.default_rng(seed)
    x = rng.standard_normal((10, 3))
    for c in (1.5, -1.5, 0.0):
        y = c * x + 0.3 * rng.standard_normal((10, 3))
        coef, rnorm = nnls(x.reshape(-1, 1), y.reshape(-1))
        assert _rss_one(y, x) == pytest.approx(rnorm**2, rel=1e-9, abs=1e-12)
    assert _rss_one(y, np.zeros_like(y)) == pytest.approx(float((y * y).sum()))


def _burns(theta: np.ndarray, n_ticks: int, seed: int, below: float = 0.6) -> list[int | None]:
    """generic's six thrusters pulsing at random with actual thrust ``theta`` (over nominal),
    gyro-like noise on the residual; the test's answer after every learning tick."""
    rng = np.random.default_rng(seed)
    eff = Effectiveness(MU, bound=0.2, r_var=1e-4**2, tick_s=H)
    eff.kept = 8
    out = []
    for _ in range(n_ticks):
        e = np.where(rng.random(6) < 0.4, rng.uniform(0.05, H, 6), 0.0)
        true = MU.T @ (theta * e)
        pred = MU.T @ (eff.k * e)
        eff.update(true - pred + 2e-5 * rng.standard_normal(3), e, np.ones(6, bool))
        out.append(eff.weak(below, 3.0, 8, np.ones(6, bool)))
    return out


@pytest.mark.parametrize("seed", range(3))
def test_a_thruster_at_40_percent_is_named_and_none_at_the_envelope_edge(seed: int) -> None:
    """Thruster 0 gives 40 %: named within 60 ticks, and only it. Every thruster at the
    envelope's worst (0.85 x 0.85 = 0.72, DESIGN 10) or above: never named in 600 ticks."""
    got = _burns(np.array([0.4, 0.72, 1.0, 1.15, 0.85, 0.72]), 60, seed)
    named = {x for x in got if x is not None}
    assert named == {0}, got
    clean = _burns(np.array([0.72, 0.72, 0.72, 1.3, 0.85, 0.72]), 600, seed + 10)
    assert all(x is None for x in clean)


def test_a_restore_forgets_the_burns_before_it() -> None:
    rng = np.random.default_rng(4)
    eff = Effectiveness(MU, bound=0.2, r_var=1e-4**2, tick_s=H)
    theta = np.array([0.3, 1, 1, 1, 1, 1.0])
    for _ in range(60):
        e = np.where(rng.random(6) < 0.5, rng.uniform(0.05, H, 6), 0.0)
        eff.update(MU.T @ ((theta - eff.k) * e), e, np.ones(6, bool))
    assert eff.weak(0.6, 3.0, 8, np.ones(6, bool)) == 0
    eff.restore()
    assert eff.weak(0.6, 3.0, 8, np.ones(6, bool)) is None
    # ... and an unavailable thruster (dropped, manifold closed) is never named
    for _ in range(60):
        e = np.where(rng.random(6) < 0.5, rng.uniform(0.05, H, 6), 0.0)
        eff.update(MU.T @ ((theta - eff.k) * e), e, np.ones(6, bool))
    assert eff.weak(0.6, 3.0, 8, np.array([False, True, True, True, True, True])) is None


def _window(kind: str):
    """iss_rs: SM+roll1_II burns every tick of a 10-tick window (the controller holding the
    craft against something). ``leak``: P2+roll_II stuck on at 50 % (74 deg from SM+roll1_II's
    opposite), so the residual is that leak; ``deficit``: SM+roll1_II gives half its thrust."""
    v = load_vehicle("iss_rs")
    fs = FlightSoftware(v, initial_attitude=AttitudeCfg(axis=(1, 0, 0), angle_deg=0.0))
    names = list(fs.arrays.names)
    i, j = names.index("SM+roll1_II"), names.index("P2+roll_II")
    mu = fs.arrays.mu_B_rad_s2
    rng = np.random.default_rng(0)
    fs._window = []
    for k in range(10):
        eff = np.zeros(fs.n)
        eff[i] = H
        cause = 0.5 * mu[j] * H if kind == "leak" else -0.5 * mu[i] * H
        raw = cause + 2e-7 * rng.standard_normal(3)
        fs._window.append((raw, eff, True, raw, k))
    return fs._weak_detection(i), names[i]


def test_a_leak_fought_by_a_thruster_is_not_named_that_thruster_degraded() -> None:
    (named, found), _ = _window("leak")
    assert named is None and found is None


def test_a_deficit_along_the_thruster_is_named_degraded() -> None:
    (named, found), who = _window("deficit")
    assert named is not None and named.kind == DEGRADED and who in named.names
    assert named.source == "effectiveness"


def test_closed_loop_iss_rs_degraded_inside_the_dead_zone_is_named() -> None:
    """iss_rs, 20 deg slew, P2+pitch_I at 40 % from 5 s: each burn's deficit is inside the
    2e-6 rad/s dead zone, so without the test nothing is found in 60 s; with it, P2+pitch_I
    degraded within 10 s."""
    init = InitialCfg(attitude=AttitudeCfg(axis=(1, 0, 0), angle_deg=20.0))
    fault = [FaultSpec(kind="degraded", t_s=5.0, thruster="P2+pitch_I", fraction=0.4)]
    # the burn-fraction test alone: the test pulses (which judge its finding) off
    quiet = {"pulse_test_below": None}
    dets, _, _ = _run("iss_rs", fault, 60.0, init=init, flight={"detector": quiet})
    assert dets, "not detected"
    t, d = dets[0]
    assert (d.names, d.kind, d.source) == (("P2+pitch_I",), DEGRADED, "effectiveness")
    assert t <= 15.0 and d.fraction == pytest.approx(0.4, abs=0.15)
    off, _, _ = _run("iss_rs", fault, 60.0, init=init,
                     flight={"detector": {**quiet, "weak_below": None, "weak_small_below": None,
                                          "weak_degraded_below": None}})
    assert off == []


def test_the_test_without_the_learning_is_refused() -> None:
    with pytest.raises(ConfigError, match=r"weak_below: expected none when "
                                          r"effectiveness_bound is 0.*got 0\.6"):
        load_vehicle("iss_rs", {"detector": {"effectiveness_bound": 0.0,
                                             "relative_dead_zone_sigma": None,
                                             "flex_share": 0.0,
                                             "learn_latency_ms": 0.0}})
