"""The leak-fit test (issue 12): a thruster stuck on at a fraction of its thrust adds its
acceleration on every tick its valve should be closed; over 25 ticks that is found even when
each tick's share sits inside the per-tick dead zone.

Oracles: the leak and the deficit the synthetic residuals are built from (a leak pushes along
its thruster's acceleration on its closed-valve time, a weak thruster falls short along its
own on its burns); pure noise of the configured size names nothing.
"""

from __future__ import annotations

import numpy as np
import pytest

from flight.detector import STUCK_ON
from flight.software import FlightSoftware
from hil.config import AttitudeCfg, load_vehicle

H = 0.2


def _flight() -> FlightSoftware:
    return FlightSoftware(load_vehicle("iss_rs"),
                          initial_attitude=AttitudeCfg(axis=(1, 0, 0), angle_deg=0.0))


def _feed(fs: FlightSoftware, cause, ticks: int, seed: int = 0):
    """``ticks`` calls of the test, each after one more tick in its window: random pulses of
    every thruster but the leaking one, residual ``cause(mu, eff)`` plus gyro-size noise."""
    rng = np.random.default_rng(seed)
    mu = fs.arrays.mu_B_rad_s2
    dz = fs.detector.dead_zone_rad_s()
    found = []
    for t in range(ticks):
        eff = np.where(rng.random(fs.n) < 0.15, rng.uniform(0.02, H, fs.n), 0.0)
        eff[_idx(fs, "SM-yaw_I")] = 0.0
        raw = cause(mu, eff) + 2.8e-7 * rng.standard_normal(3)
        fs._leak_window.append((raw, eff, (dz / 3.0) ** 2, t))
        del fs._leak_window[:-fs.detector.cfg.leak_fit_ticks]
        found.append(fs._leak_fit())
    return [d for d in found if d is not None]


def _idx(fs: FlightSoftware, name: str) -> int:
    return list(fs.arrays.names).index(name)


def test_a_leak_is_named_after_the_window_and_the_hold() -> None:
    fs = _flight()
    j = _idx(fs, "SM-yaw_I")
    cfg = fs.detector.cfg
    found = _feed(fs, lambda mu, eff: 0.3 * mu[j] * H, cfg.leak_fit_ticks + cfg.leak_fit_hold)
    assert len(found) == 1
    d = found[0]
    assert d.kind == STUCK_ON and "SM-yaw_I" in d.names and d.source == "leak_fit"
    assert d.rho == pytest.approx(0.3, abs=0.1)  # the fitted leak


def test_a_weak_burning_thruster_is_not_read_as_a_leak() -> None:
    fs = _flight()
    i = _idx(fs, "P2+pitch_I")
    found = _feed(fs, lambda mu, eff: -0.5 * eff[i] * mu[i], 200, seed=1)
    assert found == []


@pytest.mark.parametrize("seed", range(3))
def test_noise_alone_names_nothing(seed: int) -> None:
    fs = _flight()
    assert _feed(fs, lambda mu, eff: np.zeros(3), 300, seed=seed) == []


def test_off_by_default() -> None:
    assert load_vehicle("generic").flight.detector.leak_fit_min is None
