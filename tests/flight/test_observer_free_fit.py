"""The adaptive observer's frequency fitted on the free ringing (``observer.freq_prior_sigma``)
and the dead zone it widens (``detector.flex_freq_dead_zone``), flight/observer.py.

Truth: a rigid rate plus a damped tone at the gyro, g(n+1) = A g(n) - B g(n-1) + mu u(n),
excited by a slew (a thruster on every tick: no quiet tick for the NLMS step to learn from),
then free ringing; white gyro noise. The oracle is the tone's own frequency; the fit must find
it within a few seconds of quiet ticks where the NLMS step alone has barely moved.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from flight.observer import AdaptiveObserver
from hil.config import ObserverCfg

H = 0.2
GAINS = (0.75, 0.3, -0.1, 0.05, 0.75, 0.3, -0.1, 0.1)
F0 = 0.3
DELTA = 0.04


def _observer(prior_sigma: float | None) -> AdaptiveObserver:
    return AdaptiveObserver(ObserverCfg(gains=GAINS, initial_freq_hz=F0, initial_damping=0.01,
                                        mu_bound=0.1, freq_prior_sigma=prior_sigma), H)


def _fly(obs: AdaptiveObserver, f_true: float, slew_ticks: int = 30, quiet_ticks: int = 25,
         leak: float = 0.0, seed: int = 5) -> list[np.ndarray]:
    """Slew (random burns on every tick, channel x), then quiet; ``leak``: an unmodelled rate
    increment on every tick after the slew (a thruster stuck on that the model does not
    know). Returns the observer's frequency after each tick."""
    rng = np.random.default_rng(seed)
    A = 2 * math.exp(-DELTA * f_true * H) * math.cos(2 * math.pi * f_true * H)
    B = math.exp(-2 * DELTA * f_true * H)
    w, g, g_prev, u_prev = 0.0, 0.0, 0.0, 0.0
    freqs = []
    for n in range(slew_ticks + quiet_ticks):
        y = np.array([w + g, 0.0, 0.0]) + 5e-6 * rng.standard_normal(3)
        freqs.append(obs.update(y, np.zeros(3), np.array([u_prev, 0.0, 0.0])).freq_hat_hz)
        u = rng.uniform(0.5, 1.0) * 4e-3 * (1 if (n // 5) % 2 else -1) if n < slew_ticks else 0.0
        g, g_prev = A * g - B * g_prev + 0.3 * u, g
        w += u + (leak if n >= slew_ticks else 0.0)
        u_prev = u
    return freqs


@pytest.mark.parametrize("factor", [0.7, 1.35])
def test_the_fit_finds_the_tone_within_a_few_seconds_of_free_ringing(factor: float) -> None:
    """A tone 0.7 or 1.35 times the prior: 2 s into the quiet the fit is within 2 % of it (and
    stays so), where the NLMS step alone is still more than 10 % off (the oracle that the fit
    is what finds it)."""
    f_true = factor * F0
    fit = _fly(_observer(0.2), f_true)
    nlms = _fly(_observer(None), f_true)
    assert fit[29][0] == pytest.approx(F0)  # the slew taught neither anything
    assert nlms[29][0] == pytest.approx(F0)
    for f in fit[40:]:
        assert f[0] == pytest.approx(f_true, rel=0.02)
    assert abs(nlms[40][0] - f_true) > 0.1 * f_true


def test_a_leak_during_the_ringing_does_not_drag_the_fit() -> None:
    """A constant unmodelled increment (3e-5 rad/s a tick, a tenth of the tone's increments)
    on every quiet tick: the fit's constant takes it, the frequency stays within 2 %."""
    f_true = 0.75 * F0
    assert _fly(_observer(0.2), f_true, leak=3e-5)[-1][0] == pytest.approx(f_true, rel=0.02)


def test_flex_sigma_is_the_prior_until_the_fit_knows_better() -> None:
    """Before any free ringing the flex prediction's uncertainty is |g^| |dA/df| sigma f0 (the
    closed form of A = 2 sqrt(B) cos(2 pi f h)); after it, under a third of that."""
    obs = _observer(0.2)
    rb = math.exp(-0.01 * F0 * H)
    sigma_a0 = 2 * rb * 2 * math.pi * H * math.sin(2 * math.pi * F0 * H) * 0.2 * F0
    _fly(obs, 0.8 * F0, quiet_ticks=0)
    np.testing.assert_allclose(obs.flex_sigma(), sigma_a0 * np.abs(obs.g), rtol=1e-12)
    assert obs.flex_sigma()[0] > 0.0
    flown = _observer(0.2)
    _fly(flown, 0.8 * F0)
    assert flown.sigma_A[0] < sigma_a0 / 3.0


def test_without_a_prior_there_is_no_fit_and_no_flex_sigma() -> None:
    obs = _observer(None)
    _fly(obs, 0.8 * F0)
    np.testing.assert_array_equal(obs.flex_sigma(), np.zeros(3))
    assert obs.A_fit is None


def test_reset_keeps_the_fitted_frequency_and_resync_keeps_a() -> None:
    """After a detection's response (``reset``) the fitted frequency stays: its constant kept
    any stuck thrust out of it. A gyro jump (``resync``) keeps A^ and starts the triples
    again."""
    obs = _observer(0.2)
    _fly(obs, 0.75 * F0)
    f_fit = float(obs.freq_hz()[0])
    assert f_fit == pytest.approx(0.75 * F0, rel=0.02)
    obs.resync(np.zeros(3))
    assert float(obs.freq_hz()[0]) == f_fit and obs._zs == []
    obs.reset(np.zeros(3))
    assert float(obs.freq_hz()[0]) == pytest.approx(f_fit, rel=1e-12)
    assert _observer(0.2).freq_hz()[0] == pytest.approx(F0)  # a new one starts at the prior


def test_the_dead_zone_widens_by_the_extra_and_only_by_it() -> None:
    from flight.detector import Detector
    from hil.config import DetectorCfg

    det = Detector(np.eye(3), DetectorCfg(dead_zone_rad_s=1e-4))
    dz = det.dead_zone_rad_s()
    dw = np.array([1.5 * dz, 0.0, 0.0])
    assert not det.project(dw)[2]
    assert det.project(dw, extra_rad_s=0.6 * dz)[2]
    assert not det.project(dw, extra_rad_s=0.4 * dz)[2]


def test_the_dead_zone_option_without_its_prior_is_refused() -> None:
    from common.errors import ConfigError
    from hil.config import load_vehicle

    with pytest.raises(ConfigError, match=r"detector\.flex_freq_dead_zone: expected null unless "
                                          r"observer\.kind is adaptive with freq_prior_sigma"):
        load_vehicle("orel", {"observer": {"freq_prior_sigma": None},
                              "detector": {"flex_freq_dead_zone": 2.0}})


def _orel(k: float | None, cap: float = 0.6):
    from flight.software import FlightSoftware
    from hil.config import load_vehicle

    return FlightSoftware(load_vehicle("orel", {
        "observer": {"freq_prior_sigma": 0.2},
        "detector": {"flex_freq_dead_zone": k, "flex_freq_dead_zone_cap": cap}}))


@pytest.mark.parametrize("g_roll", [1e-4, 5e-4, 0.15])
def test_the_flight_widens_its_dead_zone_by_the_flex_uncertainty_up_to_its_cap(g_roll) -> None:
    """On a quiet tick (nothing commanded) a roll residual is inside when it is under the
    absolute dead zone plus min(k |sigma_A g^|, cap dz): written out here from the prior's
    sigma_A; a flex estimate of 0.15 rad/s (a stuck thrust taken in as flex, orel-stuck run
    25) widens it by the cap only."""
    from types import SimpleNamespace

    fs, base = _orel(1.0), _orel(None)
    for f in (fs, base):
        f.observer.g = np.array([g_roll, 0.0, 0.0])
    pred = SimpleNamespace(eff_s=None, deff_dlat=None, dw_thr_abs_rad_s=0.0)
    avail = fs.fdir.available
    dz = fs.detector.dead_zone_rad_s()
    extra = min(1.0 * fs.observer.sigma_A0[0] * g_roll, 0.6 * dz)
    for r in (0.99 * (dz + extra), 1.01 * (dz + extra)):
        dw = np.array([r, 0.0, 0.0])
        assert fs._inside(dw, pred, avail) == (r < dz + extra)
        assert base._inside(dw, pred, avail) == (r < dz)


def test_a_fault_free_orel_run_alarms_without_the_widening_and_not_with_it(tmp_path) -> None:
    """orel-envelope-2 run 170 (roll mode at 0.70x its prior, a slew with a thruster on every
    tick for 6 s): with orel's settings no detection; without the widening a middle-belt
    thruster is named stuck on at 7.4 s, the first quiet ticks of the ringing (the oracle
    that the test can fail)."""
    from tests.flight.campaign_run import campaign_run

    _, r = campaign_run(tmp_path, "orel-envelope-2", 170)
    assert r.summary["detections"] == []
    _, r0 = campaign_run(tmp_path / "off", "orel-envelope-2", 170,
                         {"flex_freq_dead_zone": "null"})
    dets = r0.summary["detections"]
    assert dets and dets[0]["type"] == "stuck_on" and dets[0]["t_s"] < 10.0, dets


def test_every_dead_zone_form_takes_the_flex_term() -> None:
    """The ellipsoids (``in_ellipsoid``, ``in_learnt_ellipsoid``) add diag(flex_sigma)^2 to
    their S, written out: with nothing commanded, a residual of 1.5 dead zones along x is
    outside, and inside with a flex sigma of 1.2 dead zones on x (1.5^2 < 1 + 1.2^2)."""
    from flight.detector import Detector
    from hil.config import DetectorCfg

    dz = 1e-4
    dw = np.array([1.5 * dz, 0.0, 0.0])
    flex = np.array([1.2 * dz, 0.0, 0.0])
    det = Detector(np.eye(3), DetectorCfg(dead_zone_rad_s=dz, relative_dead_zone=0.1,
                                          relative_dead_zone_across=0.05))
    assert not det.in_ellipsoid(dw, np.zeros(3))
    assert det.in_ellipsoid(dw, np.zeros(3), flex)
    learnt = Detector(np.eye(3), DetectorCfg(dead_zone_rad_s=dz, relative_dead_zone_sigma=3.0))
    assert not learnt.in_learnt_ellipsoid(dw, np.zeros((3, 3)))
    assert learnt.in_learnt_ellipsoid(dw, np.zeros((3, 3)), flex)
